"""``python -m rvr_addon`` == the ``rvr`` command."""
import sys

from .cli import main

sys.exit(main())
