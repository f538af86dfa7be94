"""Thermal-error compensation retrofit for machine tools, one package with its parts:

- ``contract``: the one home of the facts host, header, box and controller share;
- ``host``: runs, sensor selection, fitting, effects, evaluation, reports, the ``host`` command;
- ``codegen``: model.json as a C header (fixed point, proven bounds, CRC);
- ``hil``: the firmware over a pseudo-terminal, checked line by line against the host;
- ``cnc``: the LinuxCNC side (HAL component, configuration, headless sessions).

Kept free of imports: LinuxCNC's /usr/bin/python3 loads ``thermal_comp.cnc.thermalcomp``
with the standard library only.
"""
