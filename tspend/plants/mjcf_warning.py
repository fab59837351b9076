"""The warning category of a model's departures from the paper's ODE."""


class ModelWarning(UserWarning):
    """A MuJoCo model departs from the paper's cart-pole ODE (printed as one line)."""


def print_as_one_line() -> None:
    """Show ModelWarnings as ``tspend: warning: ...`` lines on stderr (the CLI's style);
    other warnings keep Python's format."""
    import sys
    import warnings

    previous = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, ModelWarning):
            print(f"tspend: warning: {message}", file=file or sys.stderr)
        else:
            previous(message, category, filename, lineno, file, line)

    warnings.showwarning = show
