"""One module per ``tactile6d`` sub-command; each exposes ``main(argv: list[str]) -> int``."""
