"""NeuVision from Python: ``from neuvision import Experiment, Run``.

:class:`Experiment` loads an experiment file, takes changes by dotted key and runs it as
``neuvision run`` does; :class:`Run` gives a recorded run's spikes, trajectory, sensors,
motor commands, stimulation and summary as numpy arrays (``lab/experiment.py``).
"""

from hub.config import ConfigError
from lab.experiment import Experiment, Run

__all__ = ["ConfigError", "Experiment", "Run"]
