"""The simulated arm's data: the paper's simulated recordings (``simulate.py``) and the physics
a real arm adds that a description leaves out (``effects.py``), used by ``pimbs simulate
--conceal`` and by the mock bus's simulated boards."""
