"""The report's items: Tables 1-3, Figs 6-11, the ε grid, AfP by β, settings compared, and
collapsed seeds; each a function ``(points, context) -> Item | None``."""
