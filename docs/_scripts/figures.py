"""Regenerate the figures of the documentation from the pages' own snippets.

Runs the snippets of each page named on the command line (default: every page with
snippets) and saves the figures they leave open as docs/tutorials/img/<page>-<k>.png, so
the images in a page are exactly what its code draws. Run from the repository root:

    OPENBLAS_NUM_THREADS=1 python docs/_scripts/figures.py [docs/tutorials/relay.md ...]
"""

import pathlib
import sys

import matplotlib


matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import snippets  # noqa: E402


IMG = snippets.DOCS / "tutorials" / "img"


def main(paths):
    IMG.mkdir(parents=True, exist_ok=True)
    for path in paths or snippets.pages():
        path = pathlib.Path(path).resolve()
        plt.close("all")
        snippets.run_page(path)
        for k, number in enumerate(plt.get_fignums(), start=1):
            out = IMG / f"{path.stem}-{k}.png"
            plt.figure(number).savefig(out, dpi=80)
            print(out.relative_to(snippets.DOCS.parent))
        plt.close("all")


if __name__ == "__main__":
    main(sys.argv[1:])
