"""The co-simulation harness: closes the loop between the master, the gateware and the plant."""
