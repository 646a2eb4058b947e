"""gridplace: visual place recognition with sub-linear storage growth."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("gridplace")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+source"
