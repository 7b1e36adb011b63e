"""The thesis's reference experiment, which microcal reproduces and compares against.

"Vision based automatic calibration of microrobotic system", master's thesis, Tampere
University of Technology, 2012. One module per kind of content: :mod:`.figures` (published
numbers), :mod:`.experiment` (workspace, test poses, split), :mod:`.cameras` (its cameras as
models) and :mod:`.kinematics` (the simulator's preset sized after its figures).
"""
