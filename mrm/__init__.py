"""The ``mrm`` command line: argument parsing, flag names and exit codes, nothing else.

Library code raises :class:`mrm_cosim.errors.InputError` naming configuration fields and API
arguments; :mod:`mrm_cosim.mrm.cli` maps them to flags and exit codes.
"""
