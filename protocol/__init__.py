"""The protocol room: the single definition of what travels on the link and how the nodes'
words are encoded. Pure Python: the master, the gateware (:mod:`mrm_cosim.hdl`) and its
bit-exact references import it; it imports none of them, nor Amaranth (docs/architecture.md
"Import rules").

* :mod:`.packet` — packet types, header, framing and the receiver's checks; :mod:`.crc` —
  the frame's CRC-16; :mod:`.link` — character codes, link states, error classes, credits
  and the codec's parameters;
* :mod:`.regs` — the node's register map, CONFIG/PARAM uploads and Comm A–D payloads;
  :mod:`.fixed` — the 24-bit fixed-point formats of every word;
* :mod:`.isa` — the multiply-accumulate engine's instruction set, compiler and scheduler;
  :mod:`.vdc_program`, :mod:`.joint_program` — the two programs the nodes run, whose register
  maps the uploads address;
* :mod:`.encoder`, :mod:`.cordic` — the build parameters and constants of the encoder
  interface and of the sine/cosine unit, shared by their gateware and references.
"""
