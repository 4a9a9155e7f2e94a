"""What the suite's figures share."""
from __future__ import annotations

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
