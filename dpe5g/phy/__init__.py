"""The physical layer of Section II–III: NR numerology and the PRS (``nr``), the TR 38.901 TDL channel of eqs. (1)–(2)
(``channel``), the signal model of eqs. (3)–(6) (``signal``), the urban propagation laws of eq. (11), path loss and
link budget (``propagation``), and the base stations' deployments (``deployment``)."""
