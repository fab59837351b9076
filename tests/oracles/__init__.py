"""Independent numpy implementations the compiled controller is tested against."""
