"""LinuxCNC bridge: the board's thermal offset applied through LinuxCNC's external axis offsets
(``tcomp linuxcnc``, docs/linuxcnc.md). ``bridge`` is the logic, ``halcomp`` the thin HAL layer."""
