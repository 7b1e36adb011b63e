"""What the tests share besides fixtures: protocol peers, the network namespace, and ways to
run the command line (importable as ``support.*``: pyproject puts ``tests`` on the path)."""
