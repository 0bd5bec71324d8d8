"""The report's items: Tables 1-3, Figs 6-11, the ε grid, AfP by β, settings compared,
collapsed seeds and advisor quality; each a function ``(points, context) -> Item | None``."""
