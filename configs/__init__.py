"""The shipped scenario files (TOML), installed as the package ``companion.scenarios``.

The files are read with :mod:`tomllib`; this module only makes the folder a package so
that ``importlib.resources`` finds them in a wheel and in an editable install alike.
"""
