"""What a process needs around a run: atomic outputs (:mod:`.outputs`), signal handling
(:mod:`.interrupts`), progress bars (:mod:`.progress`), MuJoCo's native log
(:mod:`.native_logs`), size bounds on input (:mod:`.bounds`), the one reader of a model file within them
(:mod:`.model_file`) and numba's options and cache (:mod:`.jit`).
"""
