"""``python -m tspend.cli``: the ``tspend`` command."""

import sys

from tspend.cli.main import main

sys.exit(main())
