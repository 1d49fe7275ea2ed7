"""``osgd`` and ``python -m osgd``: the command line, with the kernels pinned.

:func:`osgd.kernels.pin_kernels` must run before numpy is imported, so this
module imports nothing else until it has.
"""

from osgd.kernels import pin_kernels


def main() -> None:
    """Console-script entry point: pin the numerical kernels, then run the CLI."""
    pin_kernels()
    from osgd.cli import run  # noqa: PLC0415 (after the pin, which must precede numpy)

    run()


if __name__ == "__main__":
    main()
