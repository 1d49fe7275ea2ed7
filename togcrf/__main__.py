"""``python -m togcrf``: the ``togcrf`` command line, where the package is on the path but not installed."""

from togcrf.cli import run

if __name__ == "__main__":
    run()
