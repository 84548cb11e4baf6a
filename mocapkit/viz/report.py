"""Self-contained HTML report: skeleton player, per-frame / per-joint error, metrics table.

The page needs no network: motion data is embedded as JSON (rounded to 0.1 cm,
sub-sampled to at most ``max_fps``) and drawn on a <canvas> with a small orthographic
3-D projection (drag to orbit, wheel to zoom, play/pause, frame slider).

Motions shown side by side: the first is the ground truth (or the raw input with
``truth_first=False``), the others are inputs/cleaned results with the same skeleton
and frame count. Entries missing in an input (filled by the method) are drawn in
orange; error plots are against the first motion when it is the truth.
"""
from __future__ import annotations

import html
import json
import os
from typing import Sequence

import numpy as np

from ..errors import MocapValueError
from ..motion import Motion

_COLORS = ["#2b7bba", "#d6604d", "#1a9850", "#8073ac", "#e08214", "#4d4d4d"]


def _payload(motions: Sequence[Motion], labels: Sequence[str], max_fps: float) -> dict:
    ref = motions[0]
    step = _step(ref, max_fps)
    # follow camera: every frame is shifted so the reference root is at the origin in the
    # two horizontal axes (the vertical axis, the largest rest-pose extent, is kept)
    up = int(np.argmax(np.ptp(ref.skeleton.rest_positions(), axis=0))) if ref.n_joints > 1 else 1
    root = ref.positions[::step, 0].copy()
    root = np.where(np.isfinite(root), root, np.nanmean(ref.positions[:, 0], axis=0))
    root[:, up] = np.nanmin(ref.positions[..., up]) + 0.5 * np.nanmax(np.ptp(ref.positions[..., up], axis=1))
    out = {"fps": ref.fps / step, "parents": ref.skeleton.parents.tolist(),
           "names": list(ref.skeleton.names), "motions": []}
    for m, lab, col in zip(motions, labels, _COLORS * 4):
        P = np.round(m.positions[::step] - root[:, None, :], 1)
        P = np.where(np.isfinite(P), P, None)
        out["motions"].append({"label": lab, "color": col, "positions": P.tolist(),
                               "missing": (~m.observed[::step]).astype(int).tolist()})
    return out


def _step(m: Motion, max_fps: float) -> int:
    return max(1, int(round(m.fps / max_fps)))


def _errors(truth: Motion, others: Sequence[Motion], step: int) -> tuple[list, list, list]:
    per_frame, per_joint, table = [], [], []
    from .. import metrics

    for m in others:
        d = np.linalg.norm(m.positions - truth.positions, axis=2)     # (T, J) cm
        per_frame.append(np.round(np.nanmean(d[::step], axis=1), 3).tolist())
        per_joint.append(np.round(np.nanmean(d, axis=0), 3).tolist())
        try:
            table.append({k: v for k, v in metrics.all_metrics(truth, m).items()})
        except Exception as e:  # metrics of a partial input (NaN) are reported, not fatal
            table.append({"error": (str(e), "")})
    return per_frame, per_joint, table


def render_report(motions: Sequence[Motion], labels: Sequence[str] | None = None, *,
                  truth_first: bool = True, title: str = "mocapkit report", max_fps: float = 30.0) -> str:
    """Return the report HTML as a string (see module docstring)."""
    if not motions:
        raise MocapValueError("report needs at least one motion")
    labels = list(labels or [f"motion {i}" for i in range(len(motions))])
    ref = motions[0]
    for m, lab in zip(motions[1:], labels[1:]):
        if m.n_frames != ref.n_frames or m.skeleton.names != ref.skeleton.names:
            raise MocapValueError(
                f"{lab}: {m.n_frames} frames x {m.n_joints} joints does not match "
                f"{labels[0]} ({ref.n_frames} x {ref.n_joints}); report motions must share skeleton and frames")
    data = _payload(motions, labels, max_fps)
    errs = {"per_frame": [], "per_joint": [], "labels": labels[1:]}
    rows_html = ""
    if truth_first and len(motions) > 1:
        pf, pj, table = _errors(ref, motions[1:], _step(ref, max_fps))
        errs.update(per_frame=pf, per_joint=pj)
        keys = sorted({k for t in table for k in t})
        rows_html = "<tr><th>metric</th>" + "".join(f"<th>{html.escape(l)}</th>" for l in labels[1:]) + "<th>unit</th></tr>"
        for k in keys:
            unit = next((t[k][1] for t in table if k in t), "")
            cells = "".join(
                f"<td>{t[k][0]:.4g}</td>" if k in t and isinstance(t[k][0], (int, float)) else
                f"<td>{html.escape(str(t.get(k, ('', ''))[0]))}</td>" for t in table)
            rows_html += f"<tr><td>{html.escape(k)}</td>{cells}<td>{html.escape(unit)}</td></tr>"
    payload = json.dumps({"data": data, "errors": errs}, separators=(",", ":"))
    return _TEMPLATE.replace("__TITLE__", html.escape(title)).replace(
        "__TABLE__", rows_html or "<tr><td>no ground truth given</td></tr>").replace("__PAYLOAD__", payload)


def write_report(path: str | os.PathLike, motions: Sequence[Motion], labels: Sequence[str] | None = None, *,
                 truth_first: bool = True, overwrite: bool = False, **kw) -> None:
    """Write :func:`render_report` to ``path`` atomically (never over an input file)."""
    from ..io._atomic import atomic_write, check_output_path

    check_output_path(path, tuple(m.source.get("path") for m in motions), overwrite=overwrite)
    text = render_report(motions, labels, truth_first=truth_first, **kw)
    atomic_write(path, lambda f: f.write(text))


_TEMPLATE = r"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>__TITLE__</title>
<style>
body{font-family:system-ui,sans-serif;margin:16px;color:#222}
#views{display:flex;flex-wrap:wrap;gap:8px}
.view{border:1px solid #ccc;border-radius:4px}
.view h3{margin:4px 8px;font-size:14px}
canvas{display:block;cursor:grab}
#controls{margin:8px 0;display:flex;gap:8px;align-items:center}
#frame{width:480px}
table{border-collapse:collapse;margin-top:8px}td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px;text-align:right}
td:first-child{text-align:left}
.legend span{display:inline-block;margin-right:12px}
</style></head><body>
<h1>__TITLE__</h1>
<div id="controls"><button id="play">Pause</button>
<input id="frame" type="range" min="0" value="0"><span id="flabel"></span>
<label><input id="overlay" type="checkbox"> overlay</label></div>
<div class="legend">Drag to orbit, wheel to zoom. <span style="color:#e08214">&#9679; filled gap (missing in input)</span></div>
<div id="views"></div>
<h2>Error against the first motion</h2>
<canvas id="perframe" width="900" height="220"></canvas>
<canvas id="perjoint" width="900" height="220"></canvas>
<h2>Metrics</h2><table id="metrics">__TABLE__</table>
<script>
const P=__PAYLOAD__;const D=P.data,E=P.errors;
const T=D.motions[0].positions.length;let f=0,playing=true,yaw=0.6,pitch=0.25,zoom=1;
const slider=document.getElementById('frame');slider.max=T-1;
const views=document.getElementById('views');const canv=[];
function mk(label){const d=document.createElement('div');d.className='view';d.innerHTML='<h3>'+label+'</h3>';
 const c=document.createElement('canvas');c.width=360;c.height=400;d.appendChild(c);views.appendChild(d);canv.push(c);return c;}
function rebuild(){views.innerHTML='';canv.length=0;
 if(document.getElementById('overlay').checked){mk(D.motions.map(m=>m.label).join(' + '));}
 else D.motions.forEach(m=>mk(m.label));draw();}
let scale=1;{let lo=1e9,hi=-1e9;/* body extent after the follow camera */D.motions[0].positions.forEach(fr=>fr.forEach(p=>{if(p[0]!==null){lo=Math.min(lo,...p);hi=Math.max(hi,...p);}}));scale=280/Math.max(1,hi-lo);}
function proj(p,c){const cy=Math.cos(yaw),sy=Math.sin(yaw),cp=Math.cos(pitch),sp=Math.sin(pitch);
 const x=cy*p[0]+sy*p[2],z=-sy*p[0]+cy*p[2];const y=cp*p[1]-sp*z;
 return [c.width/2+x*scale*zoom,c.height*0.5-y*scale*zoom];}
function drawMotion(ctx,c,m){const fr=m.positions[f],miss=m.missing[f];ctx.strokeStyle=m.color;ctx.lineWidth=2;
 D.parents.forEach((p,j)=>{if(p<0||fr[j][0]===null||fr[p][0]===null)return;const a=proj(fr[j],c),b=proj(fr[p],c);
  ctx.beginPath();ctx.moveTo(a[0],a[1]);ctx.lineTo(b[0],b[1]);ctx.stroke();});
 fr.forEach((q,j)=>{if(q[0]===null)return;const a=proj(q,c);ctx.fillStyle=miss[j]?'#e08214':m.color;
  ctx.beginPath();ctx.arc(a[0],a[1],miss[j]?4:2.5,0,7);ctx.fill();});}
function draw(){const ov=document.getElementById('overlay').checked;
 canv.forEach((c,i)=>{const ctx=c.getContext('2d');ctx.clearRect(0,0,c.width,c.height);
  if(ov)D.motions.forEach(m=>drawMotion(ctx,c,m));else drawMotion(ctx,c,D.motions[i]);});
 slider.value=f;document.getElementById('flabel').textContent='frame '+f+' / '+(T-1)+'  ('+(f/D.fps).toFixed(2)+' s)';
 plot('perframe',E.per_frame,'mean joint error per frame (cm)',f);}
function plot(id,series,title,mark){const c=document.getElementById(id),ctx=c.getContext('2d');ctx.clearRect(0,0,c.width,c.height);
 ctx.fillStyle='#222';ctx.font='13px sans-serif';ctx.fillText(title,50,14);if(!series.length)return;
 let hi=0;series.forEach(s=>s.forEach(v=>{if(v!==null&&isFinite(v))hi=Math.max(hi,v);}));hi=hi||1;
 const n=series[0].length,x0=50,w=c.width-60,y0=c.height-20,h=c.height-40;
 ctx.strokeStyle='#999';ctx.strokeRect(x0,y0-h,w,h);ctx.fillText(hi.toFixed(2),4,y0-h+10);ctx.fillText('0',30,y0);
 series.forEach((s,i)=>{ctx.strokeStyle=D.motions[i+1].color;ctx.beginPath();
  s.forEach((v,k)=>{const X=x0+w*k/Math.max(1,n-1),Y=y0-h*(v||0)/hi;k?ctx.lineTo(X,Y):ctx.moveTo(X,Y);});ctx.stroke();});
 if(mark!==undefined){ctx.strokeStyle='#000';const X=x0+w*mark/Math.max(1,n-1);ctx.beginPath();ctx.moveTo(X,y0);ctx.lineTo(X,y0-h);ctx.stroke();}}
function bars(){const c=document.getElementById('perjoint'),ctx=c.getContext('2d');ctx.font='13px sans-serif';ctx.fillStyle='#222';
 ctx.fillText('mean error per joint (cm)',50,14);if(!E.per_joint.length)return;let hi=0;E.per_joint.forEach(s=>s.forEach(v=>{if(v!==null)hi=Math.max(hi,v)}));hi=hi||1;
 const J=D.names.length,k=E.per_joint.length,bw=(c.width-60)/J/k;E.per_joint.forEach((s,i)=>{ctx.fillStyle=D.motions[i+1].color;
 s.forEach((v,j)=>{const hh=(c.height-40)*(v||0)/hi;ctx.fillRect(50+(j*k+i)*bw,c.height-20-hh,Math.max(1,bw-1),hh);});});}
document.getElementById('play').onclick=e=>{playing=!playing;e.target.textContent=playing?'Pause':'Play';};
slider.oninput=e=>{f=+e.target.value;draw();};
document.getElementById('overlay').onchange=rebuild;
let drag=null;document.addEventListener('mousedown',e=>{if(e.target.tagName==='CANVAS'&&e.target.parentNode.className==='view')drag=[e.clientX,e.clientY];});
document.addEventListener('mouseup',()=>drag=null);
document.addEventListener('mousemove',e=>{if(!drag)return;yaw+=(e.clientX-drag[0])*0.01;pitch+=(e.clientY-drag[1])*0.01;drag=[e.clientX,e.clientY];draw();});
views.addEventListener('wheel',e=>{e.preventDefault();zoom*=e.deltaY<0?1.1:0.9;draw();},{passive:false});
rebuild();bars();
setInterval(()=>{if(playing){f=(f+1)%T;draw();}},1000/D.fps);
window.mocapkitReport={frames:T,get frame(){return f},get playing(){return playing}};
</script></body></html>
"""
