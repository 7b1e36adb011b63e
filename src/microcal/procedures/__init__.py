"""Procedures (layer 4): whole tasks built from the math, vision and device layers."""
