"""Every file format and every data-set generator: the one place that parses bytes.

Nothing in `data` imports `loopclosure`, `slam` or `evaluation`.
"""
