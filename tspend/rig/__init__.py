"""The same controller on a real pendulum: the rig wire protocol (:mod:`~tspend.rig.protocol`),
the host's links and the plug-in class for a lab's hardware (:mod:`~tspend.rig.links`), the
real-time runner (:mod:`~tspend.rig.runner`, :mod:`~tspend.rig.closed_loop`), the simulated
rig (:mod:`~tspend.rig.double`), replay (:mod:`~tspend.rig.replay`) and the reference rig
end in C (``rig_end.c``).  docs/rig.md is the guide."""
