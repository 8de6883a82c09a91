"""Evaluation: everything that measures the method rather than being it.

The paper's reproduction and figures, the comparison with peers (Open3D, small_gicp), the
realistic benchmark, the capture sweep, the timing bench and the known-model baseline. Not
imported by `jaxpose` itself; the CLI imports these modules when a command needs them, and
they need the `cli`/`peers` extras (matplotlib, small_gicp, Open3D).
"""
