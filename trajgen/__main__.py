"""``python -m trajgen``: the same as the ``trajgen`` command."""

import sys

from trajgen.cli import main

sys.exit(main())
