"""Who the simulated instruments say they are: one owner for the wire back ends and ``simulate``.

The wire-level back ends (``gyrolab.sim.bench``) answer their identity queries with these
strings, and ``gyrolab simulate`` records the same identities in its bench metadata, so a
simulated recording names the instruments that ``acquire --bench sim`` would have talked to.
"""

from __future__ import annotations

#: ``*IDN?`` of the simulated HP/Agilent 34401A (a real 34401A answers serial ``0``).
AGILENT_34401A_IDN = "HEWLETT-PACKARD,34401A,0,11-5-2"
#: ``*IDN?`` of the simulated Keysight 34465A.
KEYSIGHT_34465A_IDN = "Keysight Technologies,34465A,MY59000001,A.03.01-03.15-03.01-00.52-04-02"
#: ``ROM?`` and ``TYPE?`` (dry-bulb sensor T, controller model, max temperature) of the
#: simulated ESPEC P-300.
ESPEC_P300_ROM = "P300 ROM Ver1.20"
ESPEC_P300_TYPE = "T,S4,200.0"
#: The Watlow F4 has no identity query; this names the simulated one and its address.
WATLOW_F4 = "Watlow F4 (simulated), Modbus RTU address 1"
