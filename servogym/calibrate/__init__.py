"""A digital twin from a hardware trace: fit a plant (and the loop latency) to what a
controller recorded, by replaying the trace through the simulator (docs/calibrate.md).

Example:
    >>> from servogym.calibrate import calibrate, read_trace  # doctest: +SKIP
    >>> trace = read_trace("trace.csv", "pmd")
    >>> cal = calibrate(trace, params, "rotary")
    >>> cal.plant["load_inertia_kgm2"], cal.latency, cal.rms_error_counts
"""

from servogym.calibrate._fit import (
    MAX_ERROR_RATIO,
    Calibration,
    FitError,
    FittedValue,
    LatencyResult,
    calibrate,
    latency_candidates,
)
from servogym.calibrate._plantfile import (
    PLANT_FILE_FORMAT,
    PlantFile,
    PlantFileError,
    plant_document,
    plant_values,
    read_plant_file,
    write_plant_file,
)
from servogym.calibrate._replay import Replay, Replayer, trace_profile
from servogym.calibrate._synthetic import synthetic_trace
from servogym.calibrate._trace import (
    AUX_COLUMNS,
    MIN_TICKS,
    REQUIRED_COLUMNS,
    TRACE_FORMATS,
    Trace,
    TraceError,
    check_trace,
    parse_csv,
    read_trace,
    to_csv,
)

__all__ = [
    "AUX_COLUMNS",
    "MAX_ERROR_RATIO",
    "MIN_TICKS",
    "PLANT_FILE_FORMAT",
    "REQUIRED_COLUMNS",
    "TRACE_FORMATS",
    "Calibration",
    "FitError",
    "FittedValue",
    "LatencyResult",
    "PlantFile",
    "PlantFileError",
    "Replay",
    "Replayer",
    "Trace",
    "TraceError",
    "calibrate",
    "check_trace",
    "latency_candidates",
    "parse_csv",
    "plant_document",
    "plant_values",
    "read_plant_file",
    "read_trace",
    "synthetic_trace",
    "to_csv",
    "trace_profile",
    "write_plant_file",
]
