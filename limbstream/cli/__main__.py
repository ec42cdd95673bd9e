"""``python -m limbstream.cli``: the ``limbstream`` command."""
from limbstream.cli import console

console()
