"""Decision families: control barrier functions (``cbf``), model predictive control
(``mpc``), and the small decision problems of their own (``domains``)."""
