"""The closed loop: :mod:`.runner` (blocks of samples, endings), :mod:`.fastloop` (the same
samples in compiled code), :mod:`.sinks` (where samples go), :mod:`.metrics` (the run's
numbers) and :mod:`.simulation` (a scenario built into a loop and run: the Python API).
The loop knows no concrete plant, controller or sink.
"""
