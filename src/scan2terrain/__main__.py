"""``python -m scan2terrain``: the same as the ``scan2terrain`` command."""

import sys

from scan2terrain.cli import main

sys.exit(main())
