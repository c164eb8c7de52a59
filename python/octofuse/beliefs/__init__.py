"""Beliefs beyond Bernoulli voxels: the same WEP rules on continuous densities.

Every family here offers the operations of :class:`~octofuse.beliefs.base.Belief`: for
exponential-family beliefs (Gaussians in information form, exponential polynomials) the WEP
rule ``p_a^w p_b^(1-w)`` is a convex combination of natural parameters and exact fusion is
"multiply, then divide by the common part"; Gaussian mixtures need sampling.
"""
