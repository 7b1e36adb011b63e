"""``python -m microcal`` runs the command line."""

from .cli import main

main()
