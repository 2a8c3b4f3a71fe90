"""The receivers: what turns received signals into a position.

The correlograms both receivers share (``correlogram``); DPE's ML cost, eqs. (7)–(10) (``cost``), what a search is asked
and returns (``search_config``), its two searches (``grid_search``, the paper's; ``certified_search`` with the spline
boxes it bounds, ``spline_boxes``), the receiver that runs them (``receiver``) and the public fix (``dpe``); the OTDoA
baseline (``otdoa``) and its clock-prior fit (``toa_fit``); the NLoS-aware receivers (``dpe_nlos``, ``otdoa_nlos``).
"""
