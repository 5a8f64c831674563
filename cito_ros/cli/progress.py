"""Terminal progress for the command-line tools, through tqdm (on stderr; redrawn in place on a
terminal, a line every few seconds in a log). tqdm is imported with the first bar: a tool that shows
none (cito-plan --json, a refusal) does not pay its import."""
from __future__ import annotations

import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tqdm import tqdm


def progress_bar(total: int | None, label: str, unit: str) -> tqdm:
    from tqdm import tqdm

    return tqdm(total=total, desc=label, unit=unit, dynamic_ncols=True, file=sys.stderr,
                mininterval=0.2 if sys.stderr.isatty() else 5.0)


def advance(bar: tqdm, done: int, note: str = "") -> None:
    """Move `bar` to `done` (the sweeps report a count, the solvers an iteration number)."""
    bar.set_postfix_str(note, refresh=False)
    bar.update(done - bar.n)
