"""The protocol room: the single definition of what travels on the link and how the nodes'
words are encoded. Pure Python: the gateware, the bit-exact references and the master import
it; it imports none of them, nor Amaranth."""
