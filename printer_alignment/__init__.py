"""Vision screen printer: camera, Mark detection, XY camera gantry (core, sim, nodes)."""
