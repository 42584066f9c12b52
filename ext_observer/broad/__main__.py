"""``python -m ext_observer.broad``: the same as ``python -m ext_observer broad``."""

import sys

from ext_observer.broad.cli import main

sys.exit(main())
