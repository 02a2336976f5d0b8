"""Write the profiles of the filled wine glass (scenes/wine_glass_filled.xml)
from the wine glass's profile: the glass-air sheet, the liquid's wall (the
glass's inner wall below the fill line), the liquid's flat top and the union
solid (see lathe_shape/tools/filled_glass.py).

    python scripts/make_filled_glass.py [--fill 13.0]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lathe_shape.tools.filled_glass import write_filled_glass

ROOT = Path(__file__).resolve().parents[1]

#: Fill height of scenes/wine_glass_filled.xml (the bowl's inner wall runs
#: from z = 7.18 to 17.96, widest at 11).
FILL = 13.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fill", type=float, default=FILL, help=f"fill height (default: {FILL})")
    args = parser.parse_args()
    for path in write_filled_glass(ROOT / "scenes" / "wine_glass.csv", args.fill, ROOT / "scenes").values():
        print(path.relative_to(ROOT))


if __name__ == "__main__":
    main()
