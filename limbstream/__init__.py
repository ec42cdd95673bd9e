"""limbstream: live full-body motion capture over Zenoh from IMUs that send only segment points."""
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("limbstream")
except PackageNotFoundError:  # run from a checkout that was never installed
    __version__ = "0+unknown"
