"""Procedures: whole tasks on any rig, built from the math, vision, device and control layers.

They take arrays and callables, never files (reading and writing belong to ``formats`` and
``workflows``)."""
