"""The articulated-pendulum domain: any hinge/slide MJCF, its equations derived from the model.

:mod:`.tree` reads the compiled model, :mod:`.derive` derives and generates its equations,
:mod:`.machine` holds one model with its roles, :mod:`.domain` is what the rest of tspend
asks (docs/machines.md).
"""

__all__ = ["tree", "derive", "machine", "domain"]
