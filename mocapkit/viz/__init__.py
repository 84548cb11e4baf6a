"""Plots, animations and HTML reports."""
