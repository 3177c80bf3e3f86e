"""Exceptions whose message is one line naming the file, topic or field and the problem."""


class TrainCalibError(Exception):
    """Base of the errors the ``train-calib`` command reports as one line and exit status 2."""


class ConfigError(TrainCalibError, ValueError):
    """A configuration file (track, train, parameters) is unreadable or invalid.

    The message has the form ``<file>: <key>: <problem>``.
    """

    def __init__(self, source: str, key: str, problem: str) -> None:
        self.source = str(source)
        self.key = key
        self.problem = problem
        where = f"{self.source}: {key}" if key else self.source
        super().__init__(f"{where}: {problem}")


class BagError(TrainCalibError, OSError):
    """A bag cannot be read or written; the message names the file and the problem."""
