"""The SQP backend (``sqp``, ``sqp-rti``), one module per part:

* ``solver``: the SQP / real-time iteration loop (line search, stopping, seeding);
* ``qp_model``: what the loop needs from a QP model of the NLP (``QpModel``);
* ``condensed_qp``: the NLP condensed onto the commands, a dense QP (short horizons);
* ``sparse_qp``: every stage's variables, an OCP-structured sparse QP (long horizons);
* ``dense_qp``: the dense QP solver (DAQP/qpOASES on the rows that may bind);
* ``hpipm``: HPIPM, the sparse QP's solver, and its options;
* ``convexify``: Hessian convexification; ``optimality``: violation and complementarity.
"""
