"""Recorded logs (CSV, NMEA 0183, GPX 1.1) to the input topics of a bag (``train-calib import``).

Each reader turns one file into :class:`~train_calib.importers.records.Streams` (GNSS fixes, speeds, traction
power, SI units, stamps in ns) and reports each bad row with its line number and reason in a
:class:`~train_calib.importers.records.RowLog`; :func:`~train_calib.importers.convert.import_logs` merges the
files, sorts and checks the streams and writes the bag.
"""

from .records import ImportFormatError, RowLog, Streams

__all__ = ["ImportFormatError", "RowLog", "Streams"]
