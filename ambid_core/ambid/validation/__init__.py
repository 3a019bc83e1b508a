"""Whether ambid's printed intervals hold the truth as often as they say (``ambid validate``): the coverage
bookkeeping over many seeds (:mod:`.coverage`) and what an updated parameter's interval claims on a
nonlinear rig, from noise-free twins (:mod:`.bla_truth`)."""
