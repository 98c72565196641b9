"""What every file reader and writer shares: the error types a decoder raises, a path's ``st_mode``
and an exception as one line of text."""

from __future__ import annotations

import os
import struct
from pathlib import Path

# What a decoder raises on a damaged file: Pillow (OSError "image file is truncated", SyntaxError,
# ValueError, EOFError, struct.error) and tifffile (TiffFileError is a ValueError).
DECODE_ERRORS = (OSError, ValueError, SyntaxError, EOFError, struct.error)


def stat_mode(p: Path, error: type[Exception]) -> int | None:
    """``st_mode`` of ``p``, None when it does not exist; ``error`` for any other OS refusal
    (a name too long, permissions), whose message names the path."""
    try:
        return os.stat(p).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        raise error(f"{p}: {exc.strerror or one_line(exc)}") from exc


def one_line(exc: BaseException) -> str:
    """An exception's message on one line (its type name when it has none), for error messages."""
    return " ".join(str(exc).split()) or type(exc).__name__
