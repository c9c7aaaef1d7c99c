"""Running episodes: wiring a run (``build``, ``params``), one episode and a fleet
(``episode``, ``fleet``), the engines, and what a run produces (``results``)."""
