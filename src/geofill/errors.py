"""Named exceptions. Each one is a user-facing problem: the CLI prints ``str(exc)`` as one line
and exits with ``exc.exit_code`` without writing anything."""

from __future__ import annotations


class GeoFillError(Exception):
    """Base class of every error geofill raises on purpose."""

    exit_code = 1


class InputError(GeoFillError):
    """Something is wrong with the user's files or arrays."""

    exit_code = 2


class MissingFileError(InputError):
    """An input path does not exist or is not a regular file."""


class UnreadableFileError(InputError):
    """An input file exists but cannot be opened (permissions, I/O error)."""


class CorruptImageError(InputError):
    """The file is not a decodable image (truncated, wrong format, garbage)."""


class ImageTooSmallError(InputError):
    """An image is under the minimum side length."""


class ImageTooLargeError(InputError):
    """An image has more pixels than the configured limit (decompression-bomb guard)."""


class MaskSizeError(InputError):
    """The mask's size differs from the target's."""


class EmptyMaskError(InputError):
    """The mask marks no hole pixel."""


class MaskTooLargeError(InputError):
    """The mask covers more of the target than allowed."""


class ArrayFormatError(InputError):
    """An array given through the Python API has an unsupported shape or dtype."""


class DepthFileError(InputError):
    """A user-supplied depth map is missing, unreadable or inconsistent with the source."""


class DepthModelError(InputError):
    """A learned depth model that was asked for cannot be used (weights missing, unreadable, corrupt)."""


class InpaintModelError(InputError):
    """A LaMa inpainting model that was asked for cannot be used (weights missing, unreadable, corrupt)."""


class MatcherModelError(InputError):
    """A learned matcher that was asked for cannot be used (weights missing, unreadable, corrupt)."""


class ConfigError(GeoFillError):
    """A configuration value or file is invalid."""

    exit_code = 3


class MissingExtraError(ConfigError):
    """The configuration asks for an optional part whose extra is not installed."""


class TimeBudgetError(GeoFillError):
    """The fill ran past its time budget (``time_budget_s``)."""

    exit_code = 6


class OutputError(GeoFillError):
    """An output path cannot be written (unsupported extension, missing or read-only folder, I/O error)."""

    exit_code = 4


class ReferenceUnusable(Exception):
    """A reference photo cannot help this fill (too few matches, no reliable pose, no depth, it
    does not see the hole); the message is the reason shown to the user. The fill drops that
    reference and goes on with the others. Not a :class:`GeoFillError`: it never reaches the CLI."""


class Terminated(BaseException):
    """SIGTERM as an exception (a BaseException, like KeyboardInterrupt, so that no handler meant
    for errors swallows it): cleanup code runs, no partial output stays behind, and a batch keeps
    the records of its finished items."""


#: Exit status of a fill (or a batch with an item) that fell back to single-image inpainting
#: without ``--allow-fallback``: the output is written, but not from the reference.
EXIT_FELL_BACK = 5
#: Exit status of a batch in which at least one item failed (its reason is in results.jsonl);
#: 6 is a fill's exceeded time budget.
EXIT_ITEMS_FAILED = 7
#: Exit status when the machine ran out of memory (a MemoryError reached the CLI; nothing is written).
EXIT_OUT_OF_MEMORY = 8
#: Exit status after Ctrl-C (128 + SIGINT, the shell's convention).
EXIT_INTERRUPTED = 130
#: Exit status after SIGTERM (128 + SIGTERM).
EXIT_TERMINATED = 143
