"""The daemon as a whole: its lines (targets and serial faces), the Modbus TCP face, the
table and the remote servers, wired by the routes.  The one package that may import every
mode's package, so that a line in slave mode and one in master mode run in one process.
"""
