"""devices: facts about the real devices, in one place for the simulators and the adapters.

Plain constants and small pure functions, no I/O and no project imports:
``devices.khepera`` (Khepera II and IV geometry, wheel-speed units, the IR calibration table),
``devices.mea`` (the Multi Channel Systems 60-electrode MEA layout) and ``devices.culture``
(the cell-type codes of a culture's neurons). Sources:
``shared/reference/devices.md`` (public manuals and open-source drivers).
"""
