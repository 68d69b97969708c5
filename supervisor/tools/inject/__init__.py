"""``safety-supervisor inject CONFIG REQ``: a computed violation-injection device.

The thesis injected violations with hand-written buttons, one per requirement
(its Lst. 7).  Here z3 computes them, with the analyses' encoder
(:mod:`monitors.verify.bmc`, the same semantics as the monitor): a short trace over
the topic variables whose last tick violates REQ while every other requirement,
assumptions and variable ranges included, holds at every tick.  When that is
impossible, a MaxSAT objective keeps as many of the others as possible and the
ones that must break are named.  The trace is re-checked with the reference
interpreter (:mod:`monitors.verify.interpret`) before anything is published: a
disagreement is a bug and nothing is sent.

Published, the trace is what the supervisor steps on, so the z3 problem is
posed over the *observed* sequence of states, not just the trace: the first
tick repeated by the warm-up (as many times as the supervisor may see it), each
tick as the step policy turns messages into steps (for ``on_message``, the
half-updated states between two ticks too), and the nominal state published
afterwards.  ``--all`` injects every requirement in turn into a running
supervisor and compares what its violation log says with what was expected:
a self-test of a deployed system (stop the robot's own controller first, or it
publishes on the same topics).

The modules: ``command`` (the arguments), ``session`` (one run, ``--all``
included), ``target`` and ``schedule`` (the project and what the supervisor
steps on), ``plan`` (z3) and ``recheck`` (the interpreter), ``fields`` (what a
message can carry), ``node`` and ``player`` (publishing), ``verdict`` (the
violation log), ``report`` (printing).
"""
