"""Studies over runs: paired statistics (:mod:`.stats`), the MuJoCo-against-ODE cross-check
(:mod:`.crosscheck`, :mod:`.crosscheck_openloop`), figures (:mod:`.figures`) and time
series as tables (:mod:`.timeseries`).
"""
