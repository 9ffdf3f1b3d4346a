"""Tooling around the data path: ``bench`` (stage timings of an exported file), ``cpu`` (what the
CPU offers an int8 file), ``progress`` (a frames-done line on stderr), ``viz`` (pictures of rigs,
grids and detections).
"""
