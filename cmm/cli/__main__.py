"""`python -m cmm.cli ...`: the same as the `cmm` command."""

import sys

from . import main

sys.exit(main())
