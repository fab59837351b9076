"""Imported by the sweep's fork server as its preload: the fork server dies with the sweep.

See :mod:`tspend.sweep.lifeline`.  Imported anywhere but in a fork server (started as
``python -c 'from multiprocessing.forkserver import main; ...'``), it does nothing.
"""

from __future__ import annotations

import os
import sys

__all__: list[str] = []

if sys.argv == ["-c"] and "multiprocessing.forkserver" in sys.modules:
    from tspend.sweep.lifeline import die_with_parent

    die_with_parent(expected_parent=os.getppid())
