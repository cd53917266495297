"""Body-schema learning (torch) and mismatch diagnosis (``pimbs_learn.diagnosis``).

``from pimbs_learn import load_body_schema`` is the entry point for using a trained model;
it is imported lazily so that importing the package does not pull in torch.
"""

from __future__ import annotations

from typing import Any

__all__ = ["BodySchema", "load_body_schema"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from pimbs_learn import io

        return getattr(io, name)
    raise AttributeError(f"module 'pimbs_learn' has no attribute {name!r}")
