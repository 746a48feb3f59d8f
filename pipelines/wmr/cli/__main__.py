"""``python -m wmr.cli``: the ``wmr`` command."""

import sys

from wmr.cli import main

sys.exit(main())
