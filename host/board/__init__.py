"""The board side: what runs on or beside the CNC controller. ``link`` (the $TC frame codec), ``linkauth`` (signed
commands and uploads), ``linuxcnc`` (the HAL bridge), ``fwbuild`` (the firmware build that ``tcomp flash`` ships),
``config`` (the board configuration check).

Imports no numpy, scipy or matplotlib: the board-side install (README) runs these without the scientific stack;
tests/test_layers.py checks it."""
