"""What the suite's figures share: the arrow key of a quiver plot, and the stamp every
saved figure carries in its PNG text (the run it belongs to and a hash of the code that
drew it), so a page can be checked to show a figure of the code and run it names."""
from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Iterable

# The named run a figure belongs to (``make figures`` and ``make demo`` set it; a figure
# drawn elsewhere says "unnamed").
RUN_VARIABLE = 'MACHINE_ALIGN_RUN'
RUN_KEY, CODE_KEY, MODULES_KEY = ('machine_alignment:run', 'machine_alignment:code',
                                  'machine_alignment:modules')
ROOT = Path(__file__).resolve().parents[1]       # where the packages sit

# Where a key sits, in axes coordinates: below the axes' right corner (under the x label),
# or above it, level with a left-aligned title (where another panel lies below).
_KEY_PLACES = {'below': (0.82, -0.2), 'above': (0.87, 1.03)}


def arrow_key(ax, arrows, length: float, unit: str, where: str = 'below') -> None:
    """A key for a quiver plot's ``arrows`` at the axes' right corner, ``below`` or
    ``above`` it: an arrow of a round length near ``length`` (in the arrows' units),
    labelled with ``unit``."""
    key = float(f'{length:.0e}')
    x, y = _KEY_PLACES[where]
    ax.quiverkey(arrows, x, y, key, f'{key:g} {unit}', labelpos='E', coordinates='axes')


def code_hash(modules: Iterable[str], root: Path = ROOT) -> str:
    """SHA-256 of the files ``modules`` (paths relative to ``root``), names and contents."""
    digest = hashlib.sha256()
    for module in sorted(modules):
        digest.update(module.encode() + b'\0' + (root / module).read_bytes() + b'\0')
    return digest.hexdigest()


def save_figure(fig, path, drawn_by: Iterable[str], dpi: int = 90) -> None:
    """``fig.savefig(path)`` with the stamp in the PNG's text: the run (``$MACHINE_ALIGN_RUN``),
    the modules ``drawn_by`` (their ``__file__``; this one is added) and their hash."""
    modules = sorted({str(Path(m).resolve().relative_to(ROOT)) for m in [*drawn_by, __file__]})
    fig.savefig(path, dpi=dpi, metadata={
        'Software': 'machine_alignment', RUN_KEY: os.environ.get(RUN_VARIABLE, 'unnamed'),
        CODE_KEY: code_hash(modules), MODULES_KEY: ' '.join(modules)})


def read_stamp(path) -> dict:
    """The stamp of a PNG saved by :func:`save_figure` (run, code, modules), {} if none."""
    from PIL import Image
    with Image.open(path) as image:
        text = dict(getattr(image, 'text', {}) or {})
    if CODE_KEY not in text:
        return {}
    return {'run': text.get(RUN_KEY, ''), 'code': text[CODE_KEY],
            'modules': text.get(MODULES_KEY, '').split()}
