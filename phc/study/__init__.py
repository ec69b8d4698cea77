"""Studies of a compiled model beside a plain run: how accurate, how fast, what it looks like.

* :mod:`phc.study.accuracy` — error estimates of a run (``phc simulate --estimate-error``);
* :mod:`phc.study.linearize` — linearization about a consistent point (``phc linearize``);
* :mod:`phc.study.bench` — work-precision studies (``phc bench``), with
  :mod:`phc.study.ode_form` (the model as an ODE for scipy's integrators);
* :mod:`phc.study.profile` — where the time of a run goes (``phc simulate --profile``);
* :mod:`phc.study.plots` and :mod:`phc.study.viz` — outputs over time and the planar
  mechanism frame by frame (matplotlib, optional).

Simulation itself is :mod:`phc.simulation`, parameter studies :mod:`phc.sweep`. Nothing is
imported here: each module is imported where it is used.
"""
