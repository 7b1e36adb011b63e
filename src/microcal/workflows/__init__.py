"""Workflows: the work behind each command, one module per command.

A workflow opens what a command names (rig files, run directories, calibration files),
calls the procedures, writes what the command writes and returns a typed result; the command
line (``microcal.cli``) only parses, calls one workflow and prints. Notebooks and scripts can
call the same functions.
"""
