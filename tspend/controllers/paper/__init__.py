"""The paper's second type adaptive fuzzy controller, one module per concept:
:mod:`.bspline` (B-spline membership functions, eq. 1-5), :mod:`.rules` (rule base and
firing strengths, eq. 9-12), :mod:`.ts_model` (the T-S model and its laws, eq. 14-16,
25-26), :mod:`.compensator` (eq. 21-24, 27), :mod:`.control_law` (eq. 18-19, Lemma 1),
:mod:`.membership_shape` (the unimodal shape projection) and :mod:`.controller` (one
controller sample composed of them).
"""
