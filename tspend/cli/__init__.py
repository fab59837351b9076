"""The ``tspend`` command line: :mod:`.main` parses and dispatches, one module per
subcommand (``run``, ``crosscheck``, ``list``, ``inspect``, ``sweep``, ``export``,
``compare``, ``figures``).
"""
