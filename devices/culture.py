"""Cell-type codes of a culture's neurons, as the wire contract's ``Description.cell_type``
carries them per channel: the simulated cultures make them, the analysis reads them."""

EXCITATORY = 0
INHIBITORY = 1
