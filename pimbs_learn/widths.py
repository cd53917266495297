"""Widths of the body-schema network's two hidden layers (torch-free, for the CLI's help).

The paper's 1000-1000 network interpolates 5–30 samples many ways; on a population of drawn
arms a narrower network was as accurate or more, at a fraction of the cost, so `pimbs train`
uses ``DEFAULT_HIDDEN`` (chosen as recorded in docs/learning-notebook.md §9). The paper's
width stays what its tables, `pimbs experiment` and `pimbs train --paper` use.
"""

HIDDEN = 1000  # the paper's
DEFAULT_HIDDEN = 256  # `pimbs train`'s
