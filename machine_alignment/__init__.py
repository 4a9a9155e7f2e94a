"""machine_alignment, the application on top of the machine packages: the ``machine-align``
command line, the demo, the launcher of the simulated graphs and the benchmarks. Nothing
below (calib_core, printer_alignment, hexapod_calib) imports it."""
