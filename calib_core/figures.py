"""What the suite's figures share."""
from __future__ import annotations


def arrow_key(ax, arrows, length: float, unit: str) -> None:
    """A key for a quiver plot's ``arrows``, below the axes' right corner: an arrow of a
    round length near ``length`` (in the arrows' units), labelled with ``unit``."""
    key = float(f'{length:.0e}')
    ax.quiverkey(arrows, 0.82, -0.2, key, f'{key:g} {unit}', labelpos='E', coordinates='axes')
