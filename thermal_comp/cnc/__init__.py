"""LinuxCNC side of the box: the HAL component (thermalcomp), its ready configuration and the
headless session behind `make cnc` (docs/linuxcnc.md)."""
