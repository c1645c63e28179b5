"""Experiments: the reference scenario (``scenario``), the runs and their summary (``runs``), the command line
``python -m tools.experiment`` (``cli``), the output folders (``outdir``), the Monte Carlo study (``study``)."""
