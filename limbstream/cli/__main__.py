"""``python -m limbstream.cli``: the ``limbstream`` command."""
import sys

from limbstream.cli import main

sys.exit(main())
