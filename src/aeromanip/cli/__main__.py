"""``python -m aeromanip.cli``: the ``aeromanip`` command."""

import sys

from aeromanip.cli import main

sys.exit(main())
