"""The warning category of a model's departures from the paper's ODE."""


class ModelWarning(UserWarning):
    """A MuJoCo model departs from the paper's cart-pole ODE (printed as one line)."""
