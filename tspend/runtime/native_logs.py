"""What the native libraries would print or write on their own, kept for tspend's one line.

MuJoCo prints its warnings to stderr and appends them to ``MUJOCO_LOG.TXT`` in the
working directory; Rerun's Rust core logs to stderr.  Under the CLI, MuJoCo's warnings
are collected instead and named in the one-line error when the command fails (an MJCF
with ``timestep="nan"`` says so), no log file is written, and Rerun's log is off unless
``RUST_LOG`` asks for it.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from typing import Iterator

from tspend.runtime.errors import TspendError


def quiet_rerun() -> None:
    """Rerun's Rust log off unless the user set ``RUST_LOG`` (call before importing rerun)."""
    os.environ.setdefault("RUST_LOG", "off")


def no_mujoco_log_file() -> None:
    """MuJoCo writes no ``MUJOCO_LOG.TXT`` and prints nothing from this process on.

    For processes that run many models (a sweep's workers): their warnings are collected
    per run by :func:`mujoco_warnings` and go to the run's message.
    """
    import mujoco

    config = mujoco.MjLogConfig.get()
    config.logto_file = False
    config.logto_console = False
    config.set()


@contextmanager
def mujoco_warnings() -> Iterator[list[str]]:
    """Collect MuJoCo's warnings during the block, each once, in order of first sight.

    The list is filled as the block runs; no file is written and nothing is printed.
    """
    import mujoco

    notes: list[str] = []
    previous_callback = mujoco.get_mju_user_warning()
    previous_config = mujoco.MjLogConfig.get()
    config = mujoco.MjLogConfig.get()
    config.logto_file = False
    config.logto_console = False
    config.set()

    def note(message: object) -> None:
        text = " ".join(str(message).split())
        if text not in notes:
            notes.append(text)

    mujoco.set_mju_user_warning(note)
    try:
        yield notes
    finally:
        mujoco.set_mju_user_warning(previous_callback)
        previous_config.set()


@contextmanager
def mujoco_warnings_in_errors(active: bool = True) -> Iterator[list[str]]:
    """Collect MuJoCo's warnings for the block; a TspendError leaving it carries them.

    ``active=False`` does nothing (and does not import MuJoCo: commands that never
    touch it stay light).
    """
    notes: list[str] = []
    if not active:
        yield notes
        return
    import mujoco

    previous_callback = mujoco.get_mju_user_warning()
    previous_config = mujoco.MjLogConfig.get()
    config = mujoco.MjLogConfig.get()
    config.logto_file = False      # no MUJOCO_LOG.TXT in the user's directory
    config.logto_console = False
    config.set()
    mujoco.set_mju_user_warning(lambda message: notes.append(" ".join(str(message).split())))
    try:
        yield notes
    except TspendError as exc:
        if notes:
            unique = list(dict.fromkeys(notes))
            exc.args = (f"{exc} (MuJoCo: {'; '.join(unique[:3])})",)
        raise
    finally:
        mujoco.set_mju_user_warning(previous_callback)
        previous_config.set()
