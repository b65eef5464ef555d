"""The run-folder format's names (``tcomp-run/1``, docs/data-format.md), without numpy.

Owned here and read by host/data/runs.py (which loads, validates and writes runs with numpy) and by the board
side's recorder (host/board/recorder.py, ``tcomp record``), which writes a run on the controller without the
scientific stack."""

FORMAT = "tcomp-run/1"
ROLES = ("nut", "base", "ambient", "bearing", "motor", "structure")

TEMPERATURES = "temperatures.csv"
ERRORS = "errors.csv"
MOTION = "motion.csv"
SPINDLE = "spindle.csv"
META = "meta.json"
RUN_FILES = (META, TEMPERATURES, ERRORS, MOTION, SPINDLE)  # every file of a run folder; a run is written whole

ERROR_COLUMNS = ("time_s", "position_mm", "error_um")
ERROR_OPTIONAL = ("direction", "channel")
MOTION_COLUMNS = ("t_start_s", "t_end_s", "from_mm", "to_mm", "feed_mm_min")
SPINDLE_COLUMNS = ("time_s", "rpm")
