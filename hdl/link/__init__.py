"""SpaceWire-like link: DS SERDES, character codec, link state machine (ECSS-E-ST-50-12C).

The host-side view is :class:`hdl.link.codec.Codec` with :class:`hdl.link.chars.Char` streams.
"""
