"""Errors a user can cause, each mapped to an exit status by the CLI, and the warning of a
model that departs from its equations (:class:`ModelWarning`)."""

from __future__ import annotations


class TspendError(Exception):
    """Base of every error tspend reports as a one-line message."""

    exit_status = 1


class ScenarioError(TspendError):
    """Bad input: a scenario, model file or command-line value that cannot be used.

    The message names the file, the key and what is allowed.
    """

    exit_status = 2


class DivergenceError(TspendError):
    """The closed loop left the region where it is meaningful (non-finite or out of bounds)."""

    exit_status = 3


class ControllerError(TspendError):
    """The controller failed before the run's first sample (a plug-in whose ``reset``
    raised): nothing was run or written; the message names the exception and its line."""

    exit_status = 6


class RunRefused(TspendError):
    """A check made at the run's first sample, before any input is applied, refused to
    start it (a safety filter that cannot certify a plan from the start, with
    ``safety.refuse_unadmitted``): the run ends ``refused`` with the reason, no sample
    applied; exit status 4, as a run the task ended."""

    exit_status = 4


class OutputError(TspendError):
    """An output file could not be completed (disk full, I/O error, size limit).

    The file it would have replaced is untouched; the message names the file.
    """

    exit_status = 5



class ModelWarning(UserWarning):
    """A MuJoCo model departs from the equations its run is compared with (a run warns
    once per departure, before its first step; the CLI prints each as one line)."""
