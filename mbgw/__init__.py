"""mbgw: a Modbus gateway between Modbus TCP and Modbus RTU/ASCII serial lines."""

__version__ = "0.3.0"
