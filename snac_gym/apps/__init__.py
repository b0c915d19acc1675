"""The commands, the top layer: ``snac-gym`` (:mod:`~snac_gym.apps.cli`, a thin face over the rest), the paper's
demos and Figure 3 (:mod:`~snac_gym.apps.demo`, :mod:`~snac_gym.apps.plots`), the real-arm run
(:mod:`~snac_gym.apps.real`), the benchmarks (:mod:`~snac_gym.apps.bench`) and the studies behind SNAC's defaults
(:mod:`~snac_gym.apps.studies`)."""
