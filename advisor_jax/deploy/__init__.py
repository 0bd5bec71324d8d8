"""Export of a trained actor for the numpy car runner, and its inverse."""
