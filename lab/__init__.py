"""lab: the scientist's layer, above the hub and the simulators.

What a person does with runs rather than what a run is made of: the summary written beside
every run (``postrun``), the offline analysis of one run (``run_analysis``), behaviour metrics
from a record (``behaviour``), batch comparisons over seeds (``compare``), the calibration
of the simulated culture (``calibrate``, ``activity``) and the paper's validation
(``reproduce``).

``lab`` may import ``hub``, ``sim_network``, ``sim_robot``, ``devices`` and ``settings``;
nothing below it imports ``lab`` except the ``neuvision`` command line (``hub/cli.py``), which
dispatches to it (``tests/test_import_contract.py`` holds the rules).
"""
