"""Every exception snac-gym raises on purpose, under one base: ``except SnacGymError`` catches them all.

Each one is also the built-in exception its meaning is closest to (an unusable input is a ``ValueError``, a failed
write an ``OSError``), so code written against those keeps working. The modules that raise them import them from
here, and still offer them under their old names (``snac_gym.common.outputs.OutputFolderError``, ...).
"""

from __future__ import annotations

from pathlib import Path


class SnacGymError(Exception):
    """The base of every snac-gym exception."""


# -- inputs, files and outputs -------------------------------------------------------------------------------
class OutputFolderError(SnacGymError, ValueError):
    """An ``--out`` that cannot be used: empty, a file, not creatable or not writable."""


class OutputWriteError(SnacGymError, OSError):
    """A file that could not be written: the message names it and the free space of its disk."""


class SampleFileError(SnacGymError, ValueError):
    """A samples CSV that cannot be used; the message names the file, row and column."""


class ConfigError(SnacGymError, ValueError):
    """A config value outside its schema; the message names the field by its dotted path."""


class PolicyFileError(SnacGymError, ValueError):
    """A policy file that cannot be used: corrupt, of another format, task or observation layout."""


class MissingPolicyFileError(PolicyFileError, FileNotFoundError):
    """A policy file that does not exist."""


class MissingExtraError(SnacGymError, ImportError, ValueError):
    """An optional dependency is not installed. A ``ValueError`` too, so that every command that turns bad
    input into one line (``snac-gym demo``, ``evaluate``, ``bench``) prints it as such, not as a traceback."""


class DamagedEntry(SnacGymError, ValueError):
    """A cache entry that is unreadable, of another key, or whose checksum or values do not hold."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = Path(path), reason


class RunDirectoryError(SnacGymError, RuntimeError):
    """The output directory cannot be used: it holds another run, is in use, or does not belong to this run."""


# -- runs ------------------------------------------------------------------------------------------------------
class RolloutError(SnacGymError, RuntimeError):
    """A policy returned an unusable command, or an episode ended early; the message says where."""


class ExecutorStopped(SnacGymError, RuntimeError):
    """The executor was terminated (an interrupted or failed run) while a job was queued or running."""


class Cancelled(SnacGymError, RuntimeError):
    """A pipeline stopped because another one failed or the run was interrupted."""


# -- the real arm ----------------------------------------------------------------------------------------------
class ConnectionFailure(SnacGymError, ConnectionError):
    """The arm could not be reached, refused the connection, or dropped it mid-episode."""


class LinkDown(SnacGymError):
    """The link to the controller is down: the parent ends the run (the controller's watchdog stops the arm)."""


class ProtocolError(SnacGymError, ValueError):
    """The client sent something a UR controller would not accept."""


__all__ = [
    "Cancelled", "ConfigError", "ConnectionFailure", "DamagedEntry", "ExecutorStopped", "LinkDown", "MissingExtraError",
    "MissingPolicyFileError", "OutputFolderError", "OutputWriteError", "PolicyFileError", "ProtocolError",
    "RolloutError", "RunDirectoryError", "SampleFileError", "SnacGymError",
]  # fmt: skip
