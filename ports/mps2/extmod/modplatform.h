// pyexec.c includes this header of the full tree; the board has no platform module.
