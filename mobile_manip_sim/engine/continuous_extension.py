"""How dop853's stage-only continuous extension (the core's `dense_from_stages`) is derived:
the order conditions of a continuous Runge–Kutta extension (Hairer–Nørsett–Wanner I, §II.2 rooted
trees, §II.6 dense output), solved for the weights of the 13 stages a step already has.

Not used at run time: `tableaus.py` holds the weights written out (deriving them costs a
least-squares solve), and test_runge_kutta checks that they are what this module derives and
that they satisfy every order condition.
"""
from __future__ import annotations

import functools
import math

import numpy as np


def free_dense_weights(A: np.ndarray) -> tuple:
    """(F, F_check) of `tableaus._DOP853_FREE_F` and `_DOP853_FREE_CHECK` from DOP853's
    A[:13, :13]."""
    sixth = continuous_extension(A, 6, 7)
    fifth = continuous_extension(A, 5, 6)
    F = np.linalg.solve(hairer_basis().T, sixth)
    F_check = sum(0.5 ** (r + 1) * (sixth[r] - (fifth[r] if r < 6 else 0.0)) for r in range(7))
    return F, F_check


def rooted_trees(order: int) -> dict:
    """The rooted trees with up to `order` nodes by node count, each a sorted tuple of its
    subtrees (the leaf is ()); HNW I §II.2."""
    trees = {1: [()]}
    forests = {0: {()}}   # the multisets of trees with n nodes in all, as sorted tuples
    for n in range(1, order):
        forests[n] = {tuple(sorted((tree,) + rest)) for size in range(1, n + 1)
                      for tree in trees[size] for rest in forests[n - size]}
        trees[n + 1] = sorted(forests[n])   # a root over each forest
    return trees


def continuous_extension(A: np.ndarray, order: int, degree: int) -> np.ndarray:
    """Weights β (degree, s) of a continuous extension y(θ) = y₀ + h Σ_i b_i(θ) k_i, b_i(θ) =
    Σ_r β_ri θ^(r+1), of the s-stage method whose last row of A is b and whose last stage is
    f(y₁) (FSAL): of uniform order `order` (Σ_i b_i(θ) Φ_i(t) = θ^ρ(t)/γ(t) for every tree t
    with ρ(t) ≤ order, HNW I §II.6), with b(1) = b and b'(1) = e_s (y and y' continuous from
    step to step); the freedom left minimises the order-(order+1) residuals over θ ∈ [0.1, 0.9]
    (least squares). Raises if no such extension exists."""
    s = A.shape[0]
    trees = rooted_trees(order + 1)

    @functools.cache
    def phi(tree):   # elementary weights Φ_i(t) of every stage
        v = np.ones(s)
        for child in tree:
            v = v * (A @ phi(child))
        return v

    @functools.cache
    def nodes(tree):
        return 1 + sum(nodes(child) for child in tree)

    @functools.cache
    def gamma(tree):   # the density γ(t)
        return nodes(tree) * math.prod(gamma(child) for child in tree)

    rows, rhs = [], []
    for r in range(1, degree + 1):       # the coefficient of θ^r in each condition
        for rho in range(1, order + 1):
            for tree in trees[rho]:
                row = np.zeros(degree * s)
                row[(r - 1) * s:r * s] = phi(tree)
                rows.append(row)
                rhs.append(1.0 / gamma(tree) if rho == r else 0.0)
    for i in range(s):                   # b(1) = b, b'(1) = e_s
        rows.append(np.tile(np.eye(s)[i], degree))
        rhs.append(A[-1, i])
        rows.append(np.kron(np.arange(1.0, degree + 1), np.eye(s)[i]))
        rhs.append(1.0 if i == s - 1 else 0.0)
    C, d = np.array(rows), np.array(rhs)
    beta = np.linalg.lstsq(C, d, rcond=None)[0]
    if np.abs(C @ beta - d).max() > 1e-10:
        raise ValueError(f"no continuous extension of order {order} and degree {degree}")
    _, sigma, Vt = np.linalg.svd(C, full_matrices=False)
    null = Vt[int(np.sum(sigma > 1e-10 * sigma[0])):].T
    if null.shape[1]:
        next_rows, next_rhs = [], []
        for theta in np.linspace(0.1, 0.9, 9):
            for tree in trees[order + 1]:
                next_rows.append(np.concatenate([theta ** r * phi(tree)
                                                 for r in range(1, degree + 1)]))
                next_rhs.append(theta ** (order + 1) / gamma(tree))
        R = np.array(next_rows)
        beta = beta + null @ np.linalg.lstsq(R @ null, np.array(next_rhs) - R @ beta, rcond=None)[0]
    # Directions barely outside the null space moved the conditions off by up to ~1e-11:
    # a minimal correction (iterative refinement) puts them back to round-off.
    for _ in range(3):
        beta = beta + np.linalg.lstsq(C, d - C @ beta, rcond=None)[0]
    return beta.reshape(degree, s)


def hairer_basis() -> np.ndarray:
    """(7, 7): row j = the coefficients of θ¹..θ⁷ in the j-th basis polynomial of dop853.f's
    interpolant, θ, θ(1−θ), θ²(1−θ), θ²(1−θ)², θ³(1−θ)², θ³(1−θ)³, θ⁴(1−θ)³ (`dense_eval`)."""
    basis = np.zeros((7, 7))
    for j in range(7):
        poly = np.polynomial.polynomial.polypow([0.0, 1.0], (j + 2) // 2)
        poly = np.polynomial.polynomial.polymul(
            poly, np.polynomial.polynomial.polypow([1.0, -1.0], (j + 1) // 2))
        basis[j, :len(poly) - 1] = poly[1:]
    return basis
