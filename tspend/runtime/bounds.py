"""The documented size bounds of a scenario and of the command line (docs/reliability.md).

A scenario inside them fits in memory and starts at once; every message that enforces one
names it.  Only constants: the CLI reads them before anything heavy is imported.
"""

#: longest run accepted, in samples (10^9 samples is days of wall time)
MAX_STEPS = 1e9

#: largest scenario file read, in bytes
MAX_FILE_BYTES = 1_000_000
#: deepest nesting of tables and arrays in a scenario file or a --set value
MAX_NESTING = 32
#: longest list of numbers (x0, the sum-of-sines components, ...)
MAX_LIST = 1000
#: fuzzy sets per input, B-spline order and control points per set
MAX_TERMS = 50
MAX_BSPLINE_ORDER = 10
MAX_CONTROL_POINTS = 64
#: rules of the T-S model (product of the state and u sets) and of the compensator
MAX_RULES = 10_000
#: seeds are 63-bit integers (what every numpy seed and JSON reader handles)
MAX_SEED = 2**63 - 1
#: a scenario name: printed and used in file names
MAX_NAME = 200

#: longest dotted key of an override (--set, --grid, override()): its parts are copied
MAX_KEY = 200

#: runs in one sweep or comparison (scenarios x grid points x seeds x controllers)
MAX_RUNS = 1_000_000
#: worker processes per core (--jobs): each holds its own copy of the kernels
MAX_JOBS_PER_CORE = 4
#: a sweep's run killed past this many seconds of wall time (--run-timeout's default): the
#: longest shipped run, pendulum_mujoco_soak's 600 s, takes 15-35 s on one core
DEFAULT_RUN_TIMEOUT_S = 3600.0
#: the longest --run-timeout accepted (a week)
MAX_RUN_TIMEOUT_S = 604_800.0
#: bootstrap resamples of a comparison (--resamples)
MAX_RESAMPLES = 1_000_000
#: trials of a tuning study (tspend tune --trials, compare --tune)
MAX_TRIALS = 100_000

#: an MJCF model file, in bytes
MAX_MODEL_BYTES = 10_000_000
#: cells of one heightfield (nrow x ncol) and bodies of a model
MAX_HFIELD_CELLS = 10_000_000
MAX_BODIES = 10_000

#: a planned trajectory (tspend plan, tvlqr): shooting intervals, RK4 steps inside one
#: interval, RK4 steps of the whole NLP, and rows of the plan on the run's step (the shipped
#: plans: 150 intervals of 2 steps, 3000 rows)
MAX_PLAN_INTERVALS = 10_000
MAX_PLAN_SUBSTEPS = 1000
MAX_PLAN_RK4_STEPS = 100_000
MAX_PLAN_ROWS = 1_000_000
#: MPC: shooting intervals of the horizon and RK4 steps per interval (the shipped: 30 x 2)
MAX_MPC_HORIZON = 1000
MAX_MPC_SUBSTEPS = 100
#: identify: bootstrap replicates (each a refit) and the shortest --segment, in samples
MAX_BOOTSTRAP = 10_000
MIN_SEGMENT_SAMPLES = 10
