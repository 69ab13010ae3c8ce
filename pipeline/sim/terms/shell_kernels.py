"""The shell's numba kernels (:mod:`pipeline.sim.terms.shell`): a face's energy, gradient and
Hessian, and the passes over faces that sum them into forces, Hessian blocks and the
rounding scale.

The module is long because one face's energy, gradient and Hessian are one routine
(:func:`_face`) and its inlined helpers, kept together so that the three agree term by
term; split apart, the derivation (below) would be read across modules.

The shell, a thin shell whose energy is a property of the surface, not of its triangles:

The paper's model (Eq. 2-3) gives every spring one ``K_s`` and every hinge one ``K_b``,
so the same petal triangulated twice is two different materials (issue 31). Here the
energy is a discretization of a continuum shell (Koiter's energy, St. Venant-Kirchhoff
material), so that its value for a given deformation of the surface does not depend on
how the surface is cut into triangles, and converges as the triangles shrink.

Per face ``f`` with corners ``q0, q1, q2``, in the face's own barycentric coordinates
``xi`` (``x = q0 + xi1 e1 + xi2 e2``, ``e1 = q1 - q0``, ``e2 = q2 - q0``):

- first fundamental form (metric) ``a = [[e1.e1, e1.e2], [e1.e2, e2.e2]]``;
- rest metric ``abar``, from the face's three *grown* rest edge lengths
  ``L_e (1 + A alpha_e)`` (Eq. 6): ``abar11 = L2^2``, ``abar22 = L1^2``,
  ``abar12 = (L1^2 + L2^2 - L0^2) / 2`` (``L_k``: the edge opposite ``q_k``). Growth is
  a change of the rest metric: per-edge growth ratios (the growth curve, wrinkles' extra
  rim growth) keep their meaning;
- membrane (stretching): Green strain ``E = abar^-1 (a - abar) / 2`` (a mixed tensor),
  energy density ``lambda/2 tr(E)^2 + mu tr(E^2)`` per unit rest area, plane stress
  ``lambda = Y nu / (1 - nu^2)``, ``mu = Y / (2 (1 + nu))``; ``Y`` is the stretch
  modulus (Young's modulus times thickness). Under compression St. Venant-Kirchhoff
  stays stable down to a stretch of 1/sqrt(3) (a rim buckles long before);
- bending: ``D/2 [nu tr(M)^2 + (1 - nu) tr(M^2)]`` per unit rest area,
  ``M = abar^-1 (b - bbar)``, ``D = Y t^2 / (12 (1 - nu^2))`` for thickness ``t``;
- second fundamental form ``b`` (the "patch quadratic"): the quadratic height function
  over the face's plane that passes through the face's corners and the three vertices
  across its edges, ``z = c1 l1 l2 + c2 l2 l0 + c3 l0 l1`` (``l`` the barycentric
  coordinates; the three bubbles vanish at the corners), fitted to the heights ``w_i``
  of the opposite vertices above the face's plane at their barycentric coordinates:
  ``G c = w``, ``G_ik = bubble_k(opposite_i)``. Then ``b = Hess_xi z = sum_k c_k
  Hess bubble_k``. A boundary edge has no vertex across: another vertex near the face
  stands in (:func:`pipeline.sim.terms.shell_stencil.face_stencil`), so that the fit
  stays exact for a quadratic surface at the rim too (a ghost row, the corner mirrored
  across the edge at height 0, only where no vertex conditions the fit).

Why this bending and not the two classic ones: both the discrete-shells hinge
(``3 |e|^2 / (A1 + A2) (theta - theta0)^2``, Grinspun et al. 2003) and the mid-edge
normal average (libshell's MidedgeAverage: a face's ``b`` from the bisectors of its
edges' dihedral angles) converge on regular lattices but not on irregular
triangulations: the dihedral angle across an edge depends on where the neighbour's
far vertex lies, which neither model looks at. On Poisson-disc Delaunay meshes of a
rolled sheet both settle 16-17% above the exact energy as the mesh is refined, while
the patch quadratic (exact for any quadratic surface, whatever the triangles) falls
from 6.6% to 0.5% (``tests/test_shell.py``, ``docs``: see the module's tests).

Rest curvature: ``bbar`` at growth 0 is the input bud's own ``b`` (so the bud is at
rest); with growth it is scaled by ``sqrt(Abar(A) / Abar(0))`` (the face's linear
growth: a uniformly grown bud keeps its shape, as the paper's rest angles do), and by
``1 - B(t) beta`` with curl (Eq. 11).

Units: see :func:`pipeline.sim.terms.shell.moduli`. The pipeline scales every mesh to mean edge 1, so mesh
units change with the resolution; the moduli are given per area of the petal's size
``L`` (``sqrt`` of the mean petal area) and the thickness relative to ``L``, and turned
into mesh units there, so that the same deformation has the same energy at any
resolution.

The kernels (numba, cached): :func:`shell_forces`, :func:`shell_hessian` (3x3 blocks in
the solver's layout, see :func:`pipeline.sim.terms.shell_stencil.face_pattern`),
:func:`shell_rounding`. One routine,
:func:`_face`, computes a face's energy, gradient and (optionally) Hessian, so the
three agree. Faces are done in order, serially: the same bits on every run.

Derivatives are taken through three levels of small variables, each with simple exact
first and second derivatives: the positions as edge vectors ``V = (e1, e2, d0, d1,
d2)`` (``d_i = o_i - q0``); the primitives ``P = (a11, a12, a22, e1.d_i, e2.d_i,
(e1 x e2).d_i)``; the opposite vertices' coordinates in the face's frame ``y = (xi_i1,
xi_i2, w_i)``; then ``c = G(y)^-1 w(y)``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pipeline.sim.terms.bending import hinge_theta_derivatives

#: scratch doubles of one face's derivatives (see :func:`_views`), and of a kernel call
#: (those and :func:`_small`'s)
SCRATCH = 9 + 81 + 12 + 144 + 180 + 15 + 225 + 18 + 324 + 27 + 27 + 27 + 9 + 27 + 180
#: scratch of a crease's hinge (:func:`pipeline.sim.terms.bending.hinge_theta_derivatives`:
#: its gradient (4, 3), Hessian (4, 4, 3, 3) and work (7, 4, 3, 3))
HINGE_SCRATCH = 12 + 144 + 252
KERNEL_SCRATCH = SCRATCH + 4 * 9 + 3 + HINGE_SCRATCH


@njit(cache=True, inline="always")
def _views(s):
    """Work arrays carved from one scratch vector (no allocation of data)."""
    o = 0
    Ey = s[o:o + 9]
    o += 9
    Eyy = s[o:o + 81].reshape((9, 9))
    o += 81
    EP = s[o:o + 12]
    o += 12
    EPP = s[o:o + 144].reshape((12, 12))
    o += 144
    J = s[o:o + 180].reshape((12, 5, 3))  # dP/dV
    o += 180
    EV = s[o:o + 15].reshape((5, 3))
    o += 15
    EVV = s[o:o + 225].reshape((5, 5, 3, 3))
    o += 225
    gx = s[o:o + 18].reshape((6, 3))
    o += 18
    Hx = s[o:o + 324].reshape((6, 6, 3, 3))
    o += 324
    Jy = s[o:o + 27].reshape((9, 3))  # dy/dP: each y depends on the 3 metric entries ...
    o += 27
    Jy2 = s[o:o + 27].reshape((9, 3))  # ... and on its neighbour's (s1, s2, tau)
    o += 27
    Dc = s[o:o + 27].reshape((3, 9))  # dc/dy
    o += 27
    Sig = s[o:o + 9].reshape((3, 3))
    o += 9
    SD = s[o:o + 27].reshape((3, 9))
    o += 27
    Z = s[o:o + 180].reshape((12, 5, 3))  # d2E/dP2 dP/dV
    return Ey, Eyy, EP, EPP, J, EV, EVV, gx, Hx, Jy, Jy2, Dc, Sig, SD, Z


@njit(cache=True, inline="always")
def _small(scratch):
    """G, G^-1, Cs, Cb (3x3) and the rest second form (3,) after the face's scratch, then
    a crease hinge's gradient, Hessian and work."""
    o = SCRATCH
    G = scratch[o:o + 9].reshape((3, 3))
    Gi = scratch[o + 9:o + 18].reshape((3, 3))
    Cs = scratch[o + 18:o + 27].reshape((3, 3))
    Cb = scratch[o + 27:o + 36].reshape((3, 3))
    bbar = scratch[o + 36:o + 39]
    o += 39
    hg = scratch[o:o + 12].reshape((4, 3))
    hH = scratch[o + 12:o + 156].reshape((4, 4, 3, 3))
    hw = scratch[o + 156:o + 408].reshape((7, 4, 3, 3))
    return G, Gi, Cs, Cb, bbar, (hg, hH, hw)


@njit(cache=True, inline="always")
def _rest(L0s, L1s, L2s):
    """The grown rest metric (abar11, abar12, abar22) and its determinant, from the
    squared rest lengths of the edges opposite q0, q1, q2."""
    ab11 = L2s
    ab22 = L1s
    ab12 = 0.5 * (L2s + L1s - L0s)
    detb = ab11 * ab22 - ab12 * ab12
    return ab11, ab12, ab22, detb


@njit(cache=True, inline="always")
def _material(ab11, ab12, ab22, detb, young, nu, bend, Cs, Cb):
    """The membrane and bending matrices ``Cs, Cb`` (rest area included) that act on
    ``(d11, d12, d22)`` (a difference of metrics, or of second forms): ``W = 1/2 d^T C
    d``. Returns the rest area."""
    area = 0.5 * math.sqrt(detb)
    r11 = ab22 / detb
    r12 = -ab12 / detb
    r22 = ab11 / detb
    p0 = r11
    p1 = 2.0 * r12
    p2 = r22
    t00 = r11 * r11
    t01 = 2.0 * r11 * r12
    t02 = r12 * r12
    t11 = 2.0 * (r12 * r12 + r11 * r22)
    t12 = 2.0 * r12 * r22
    t22 = r22 * r22
    lam = young * nu / (1.0 - nu * nu)
    mu = young / (2.0 * (1.0 + nu))
    ls = 0.25 * lam * area
    ms = 0.5 * mu * area
    lb = bend * nu * area
    mb = bend * (1.0 - nu) * area
    P = (p0, p1, p2)
    T = ((t00, t01, t02), (t01, t11, t12), (t02, t12, t22))
    for r in range(3):
        for c in range(3):
            Cs[r, c] = ls * P[r] * P[c] + ms * T[r][c]
            Cb[r, c] = lb * P[r] * P[c] + mb * T[r][c]
    return area


@njit(cache=True, inline="always")
def _inverse3(G, Gi):
    """``Gi = G^-1``; returns det(G)."""
    c00 = G[1, 1] * G[2, 2] - G[1, 2] * G[2, 1]
    c01 = G[1, 2] * G[2, 0] - G[1, 0] * G[2, 2]
    c02 = G[1, 0] * G[2, 1] - G[1, 1] * G[2, 0]
    det = G[0, 0] * c00 + G[0, 1] * c01 + G[0, 2] * c02
    if det == 0.0:
        return det
    inv = 1.0 / det
    Gi[0, 0] = c00 * inv
    Gi[1, 0] = c01 * inv
    Gi[2, 0] = c02 * inv
    Gi[0, 1] = (G[0, 2] * G[2, 1] - G[0, 1] * G[2, 2]) * inv
    Gi[1, 1] = (G[0, 0] * G[2, 2] - G[0, 2] * G[2, 0]) * inv
    Gi[2, 1] = (G[0, 1] * G[2, 0] - G[0, 0] * G[2, 1]) * inv
    Gi[0, 2] = (G[0, 1] * G[1, 2] - G[0, 2] * G[1, 1]) * inv
    Gi[1, 2] = (G[0, 2] * G[1, 0] - G[0, 0] * G[1, 2]) * inv
    Gi[2, 2] = (G[0, 0] * G[1, 1] - G[0, 1] * G[1, 0]) * inv
    return det


@njit(cache=True, nogil=True, error_model="numpy")
def second_form(X, faces, opposite, ghost, crease, out):
    """The second fundamental form ``(b11, b12, b22)`` of every face into ``out (F, 3)``,
    with the arithmetic of the energy kernels (so a mesh at its own ``b`` feels no
    bending force). A face whose patch is degenerate gets 0."""
    G = np.empty((3, 3))
    Gi = np.empty((3, 3))
    w = np.empty(3)
    for f in range(faces.shape[0]):
        ok = _fit(X, faces[f], opposite[f], ghost[f], crease[f], G, Gi, w)
        if not ok:
            out[f, 0] = 0.0
            out[f, 1] = 0.0
            out[f, 2] = 0.0
            continue
        c0 = Gi[0, 0] * w[0] + Gi[0, 1] * w[1] + Gi[0, 2] * w[2]
        c1 = Gi[1, 0] * w[0] + Gi[1, 1] * w[1] + Gi[1, 2] * w[2]
        c2 = Gi[2, 0] * w[0] + Gi[2, 1] * w[1] + Gi[2, 2] * w[2]
        out[f, 0] = -2.0 * c2
        out[f, 1] = c0 - c1 - c2
        out[f, 2] = -2.0 * c1


@njit(cache=True, inline="always")
def _fit(X, v, opp, ghost, crease, G, Gi, w):
    """The patch's system ``G`` (and its inverse) and heights ``w`` at X; False if the
    face or the system is degenerate. A crease's edge (``crease[i, 0] > 0``) is fitted as
    a boundary edge is (its ghost row): the patch does not look across a crease."""
    q0x = X[v[0], 0]
    q0y = X[v[0], 1]
    q0z = X[v[0], 2]
    e1x = X[v[1], 0] - q0x
    e1y = X[v[1], 1] - q0y
    e1z = X[v[1], 2] - q0z
    e2x = X[v[2], 0] - q0x
    e2y = X[v[2], 1] - q0y
    e2z = X[v[2], 2] - q0z
    a11 = e1x * e1x + e1y * e1y + e1z * e1z
    a12 = e1x * e2x + e1y * e2y + e1z * e2z
    a22 = e2x * e2x + e2y * e2y + e2z * e2z
    det = a11 * a22 - a12 * a12
    if not det > 0.0:
        return False
    sq = math.sqrt(det)
    Q11 = a22 / det
    Q12 = -a12 / det
    Q22 = a11 / det
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    for i in range(3):
        o = opp[i]
        if o < 0 or crease[i, 0] > 0.0:
            G[i, 0] = ghost[i, 0]
            G[i, 1] = ghost[i, 1]
            G[i, 2] = ghost[i, 2]
            w[i] = 0.0
            continue
        dx = X[o, 0] - q0x
        dy = X[o, 1] - q0y
        dz = X[o, 2] - q0z
        s1 = e1x * dx + e1y * dy + e1z * dz
        s2 = e2x * dx + e2y * dy + e2z * dz
        xi1 = Q11 * s1 + Q12 * s2
        xi2 = Q12 * s1 + Q22 * s2
        l0 = 1.0 - xi1 - xi2
        G[i, 0] = xi1 * xi2
        G[i, 1] = xi2 * l0
        G[i, 2] = xi1 * l0
        w[i] = (nx * dx + ny * dy + nz * dz) / sq
    det_g = _inverse3(G, Gi)
    scale = 0.0
    for r in range(3):
        for c in range(3):
            scale = max(scale, abs(G[r, c]))
    return abs(det_g) > 1e-12 * scale * scale * scale


@njit(cache=True, inline="always", error_model="numpy")
def _face(X, v, opp, ghost, crease, L0s, L1s, L2s, young, nu, bend, bbar, curl, want, views,
          G, Gi, Cs, Cb, hinge):
    """Energy of one face (membrane and bending); its gradient into the scratch's ``gx
    (6, 3)`` and, if ``want``, its Hessian into ``Hx (6, 6, 3, 3)`` (vertex order q0,
    q1, q2, o0, o1, o2; rows of missing opposite vertices are zero). ``bbar``: the rest
    second fundamental form (growth and curl applied). ``crease (3, 2)``: the stiffness
    and rest angle of a crease this face carries across the edge opposite each corner
    (stiffness 0: none; :func:`_crease`)."""
    Ey, Eyy, EP, EPP, J, EV, EVV, gx, Hx, Jy, Jy2, Dc, Sig, SD, Z = views
    ab11, ab12, ab22, detb = _rest(L0s, L1s, L2s)
    if not detb > 0.0:  # grown lengths that break the triangle inequality: no energy
        gx[:, :] = 0.0
        if want:
            Hx[:, :, :, :] = 0.0
        return 0.0
    _material(ab11, ab12, ab22, detb, young, nu, bend, Cs, Cb)
    q0 = (X[v[0], 0], X[v[0], 1], X[v[0], 2])
    e1 = (X[v[1], 0] - q0[0], X[v[1], 1] - q0[1], X[v[1], 2] - q0[2])
    e2 = (X[v[2], 0] - q0[0], X[v[2], 1] - q0[1], X[v[2], 2] - q0[2])
    a11 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]
    a12 = e1[0] * e2[0] + e1[1] * e2[1] + e1[2] * e2[2]
    a22 = e2[0] * e2[0] + e2[1] * e2[1] + e2[2] * e2[2]
    # membrane: a quadratic in (a11, a12, a22)
    d0 = a11 - ab11
    d1 = a12 - ab12
    d2 = a22 - ab22
    EP[:] = 0.0
    g0 = Cs[0, 0] * d0 + Cs[0, 1] * d1 + Cs[0, 2] * d2
    g1 = Cs[1, 0] * d0 + Cs[1, 1] * d1 + Cs[1, 2] * d2
    g2 = Cs[2, 0] * d0 + Cs[2, 1] * d1 + Cs[2, 2] * d2
    energy = 0.5 * (d0 * g0 + d1 * g1 + d2 * g2)
    EP[0] = g0
    EP[1] = g1
    EP[2] = g2
    if want:
        EPP[:, :] = 0.0
        for r in range(3):
            for c in range(3):
                EPP[r, c] = Cs[r, c]
    # bending
    det = a11 * a22 - a12 * a12
    real = (opp[0] >= 0 and crease[0, 0] <= 0.0, opp[1] >= 0 and crease[1, 0] <= 0.0,
            opp[2] >= 0 and crease[2, 0] <= 0.0)
    bending = det > 0.0 and bend > 0.0
    if bending:
        bending = _fit(X, v, opp, ghost, crease, G, Gi, Ey[:3])
    if bending:
        w0 = Ey[0]
        w1 = Ey[1]
        w2 = Ey[2]
        c = (Gi[0, 0] * w0 + Gi[0, 1] * w1 + Gi[0, 2] * w2,
             Gi[1, 0] * w0 + Gi[1, 1] * w1 + Gi[1, 2] * w2,
             Gi[2, 0] * w0 + Gi[2, 1] * w1 + Gi[2, 2] * w2)
        b = (-2.0 * c[2], c[0] - c[1] - c[2], -2.0 * c[1])
        db = (b[0] - bbar[0], b[1] - bbar[1], b[2] - bbar[2])
        sb0 = Cb[0, 0] * db[0] + Cb[0, 1] * db[1] + Cb[0, 2] * db[2]
        sb1 = Cb[1, 0] * db[0] + Cb[1, 1] * db[1] + Cb[1, 2] * db[2]
        sb2 = Cb[2, 0] * db[0] + Cb[2, 1] * db[1] + Cb[2, 2] * db[2]
        energy += 0.5 * (db[0] * sb0 + db[1] * sb1 + db[2] * sb2)
        # dE/dc (b = Hm c, Hm's columns (0,1,0), (0,-1,-2), (-2,-1,0))
        sig = (sb1, -sb1 - 2.0 * sb2, -2.0 * sb0 - sb1)
        gam = (sig[0] * Gi[0, 0] + sig[1] * Gi[1, 0] + sig[2] * Gi[2, 0],
               sig[0] * Gi[0, 1] + sig[1] * Gi[1, 1] + sig[2] * Gi[2, 1],
               sig[0] * Gi[0, 2] + sig[1] * Gi[1, 2] + sig[2] * Gi[2, 2])
        sq = math.sqrt(det)
        Q11 = a22 / det
        Q12 = -a12 / det
        Q22 = a11 / det
        ddet = (a22, -2.0 * a12, a11)  # d det / d(a11, a12, a22)
        nvec = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0])
        Ey[:] = 0.0
        if want:
            Eyy[:, :] = 0.0
            Dc[:, :] = 0.0
        for i in range(3):
            if not real[i]:
                continue
            o = opp[i]
            d = (X[o, 0] - q0[0], X[o, 1] - q0[1], X[o, 2] - q0[2])
            s1 = e1[0] * d[0] + e1[1] * d[1] + e1[2] * d[2]
            s2 = e2[0] * d[0] + e2[1] * d[1] + e2[2] * d[2]
            tau = nvec[0] * d[0] + nvec[1] * d[1] + nvec[2] * d[2]
            xi1 = Q11 * s1 + Q12 * s2
            xi2 = Q12 * s1 + Q22 * s2
            wv = tau / sq
            # u_a = d bubbles / d xi_a
            u1 = (xi2, -xi2, 1.0 - 2.0 * xi1 - xi2)
            u2 = (xi1, 1.0 - xi1 - 2.0 * xi2, -xi1)
            rho1 = u1[0] * c[0] + u1[1] * c[1] + u1[2] * c[2]
            rho2 = u2[0] * c[0] + u2[1] * c[1] + u2[2] * c[2]
            Ey[3 * i] = -rho1 * gam[i]
            Ey[3 * i + 1] = -rho2 * gam[i]
            Ey[3 * i + 2] = gam[i]
            # dy/dP: metric part (Jy) and the neighbour's own (s1, s2, tau) part (Jy2)
            Jy[3 * i, 0] = -Q11 * xi1
            Jy[3 * i + 1, 0] = -Q12 * xi1
            Jy[3 * i, 1] = -(Q11 * xi2 + Q12 * xi1)
            Jy[3 * i + 1, 1] = -(Q12 * xi2 + Q22 * xi1)
            Jy[3 * i, 2] = -Q12 * xi2
            Jy[3 * i + 1, 2] = -Q22 * xi2
            Jy2[3 * i, 0] = Q11
            Jy2[3 * i, 1] = Q12
            Jy2[3 * i, 2] = 0.0
            Jy2[3 * i + 1, 0] = Q12
            Jy2[3 * i + 1, 1] = Q22
            Jy2[3 * i + 1, 2] = 0.0
            for m in range(3):
                Jy[3 * i + 2, m] = -0.5 * wv * ddet[m] / det
            Jy2[3 * i + 2, 0] = 0.0
            Jy2[3 * i + 2, 1] = 0.0
            Jy2[3 * i + 2, 2] = 1.0 / sq
            if want:
                Dc[0, 3 * i] = -rho1 * Gi[0, i]
                Dc[1, 3 * i] = -rho1 * Gi[1, i]
                Dc[2, 3 * i] = -rho1 * Gi[2, i]
                Dc[0, 3 * i + 1] = -rho2 * Gi[0, i]
                Dc[1, 3 * i + 1] = -rho2 * Gi[1, i]
                Dc[2, 3 * i + 1] = -rho2 * Gi[2, i]
                Dc[0, 3 * i + 2] = Gi[0, i]
                Dc[1, 3 * i + 2] = Gi[1, i]
                Dc[2, 3 * i + 2] = Gi[2, i]
                # sigma . d2c/dy2 (see the module docstring's derivation)
                for j in range(3):
                    if not real[j]:
                        continue
                    k1j = u1[0] * Gi[0, j] + u1[1] * Gi[1, j] + u1[2] * Gi[2, j]
                    k2j = u2[0] * Gi[0, j] + u2[1] * Gi[1, j] + u2[2] * Gi[2, j]
                    Eyy[3 * i, 3 * j + 2] -= k1j * gam[i]
                    Eyy[3 * j + 2, 3 * i] -= k1j * gam[i]
                    Eyy[3 * i + 1, 3 * j + 2] -= k2j * gam[i]
                    Eyy[3 * j + 2, 3 * i + 1] -= k2j * gam[i]
                    # K_{ia,j} rho_jb gamma_i, both orders (the other order adds K_{jb,i}
                    # rho_ia gamma_j when the loop reaches (j, i))
                    oj = opp[j]
                    dj = (X[oj, 0] - q0[0], X[oj, 1] - q0[1], X[oj, 2] - q0[2])
                    sj1 = e1[0] * dj[0] + e1[1] * dj[1] + e1[2] * dj[2]
                    sj2 = e2[0] * dj[0] + e2[1] * dj[1] + e2[2] * dj[2]
                    xj1 = Q11 * sj1 + Q12 * sj2
                    xj2 = Q12 * sj1 + Q22 * sj2
                    rj1 = xj2 * c[0] - xj2 * c[1] + (1.0 - 2.0 * xj1 - xj2) * c[2]
                    rj2 = xj1 * c[0] + (1.0 - xj1 - 2.0 * xj2) * c[1] - xj1 * c[2]
                    v11 = k1j * rj1 * gam[i]
                    v12 = k1j * rj2 * gam[i]
                    v21 = k2j * rj1 * gam[i]
                    v22 = k2j * rj2 * gam[i]
                    Eyy[3 * i, 3 * j] += v11
                    Eyy[3 * j, 3 * i] += v11
                    Eyy[3 * i, 3 * j + 1] += v12
                    Eyy[3 * j + 1, 3 * i] += v12
                    Eyy[3 * i + 1, 3 * j] += v21
                    Eyy[3 * j, 3 * i + 1] += v21
                    Eyy[3 * i + 1, 3 * j + 1] += v22
                    Eyy[3 * j + 1, 3 * i + 1] += v22
                Eyy[3 * i, 3 * i] -= b[0] * gam[i]
                Eyy[3 * i, 3 * i + 1] -= b[1] * gam[i]
                Eyy[3 * i + 1, 3 * i] -= b[1] * gam[i]
                Eyy[3 * i + 1, 3 * i + 1] -= b[2] * gam[i]
        # dE/dP = Jy^T Ey
        for i in range(3):
            if not real[i]:
                continue
            for r in range(3):
                yr = 3 * i + r
                for m in range(3):
                    EP[m] += Jy[yr, m] * Ey[yr]
                    EP[3 + 3 * i + m] += Jy2[yr, m] * Ey[yr]
        if want:
            _bending_EPP(Ey, Eyy, EPP, Jy, Jy2, Dc, Sig, SD, Cb, real, Q11, Q12, Q22, det,
                         sq, ddet, opp, X, q0, e1, e2)
    # from P to the edge vectors V = (e1, e2, d0, d1, d2) (dP/dV is sparse: written out),
    # then to the vertices
    nvec = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0])
    for x in range(3):
        EV[0, x] = 2.0 * EP[0] * e1[x] + EP[1] * e2[x]
        EV[1, x] = EP[1] * e1[x] + 2.0 * EP[2] * e2[x]
    for i in range(3):
        if not real[i]:
            EV[2 + i, 0] = 0.0
            EV[2 + i, 1] = 0.0
            EV[2 + i, 2] = 0.0
            continue
        o = opp[i]
        d = (X[o, 0] - q0[0], X[o, 1] - q0[1], X[o, 2] - q0[2])
        m = 3 + 3 * i
        e2xd = (e2[1] * d[2] - e2[2] * d[1], e2[2] * d[0] - e2[0] * d[2],
                e2[0] * d[1] - e2[1] * d[0])
        dxe1 = (d[1] * e1[2] - d[2] * e1[1], d[2] * e1[0] - d[0] * e1[2],
                d[0] * e1[1] - d[1] * e1[0])
        for x in range(3):
            EV[0, x] += EP[m] * d[x] + EP[m + 2] * e2xd[x]
            EV[1, x] += EP[m + 1] * d[x] + EP[m + 2] * dxe1[x]
            EV[2 + i, x] = EP[m] * e1[x] + EP[m + 1] * e2[x] + EP[m + 2] * nvec[x]
    for x in range(3):
        total = 0.0
        for A in range(5):
            total += EV[A, x]
        gx[0, x] = -total
        gx[1, x] = EV[0, x]
        gx[2, x] = EV[1, x]
        gx[3, x] = EV[2, x]
        gx[4, x] = EV[3, x]
        gx[5, x] = EV[4, x]
    if want:
        _primitive_jacobian(X, v, opp, real, e1, e2, J)
        _vertex_hessian(EP, EPP, J, Z, EVV, Hx, real, e1, e2, X, opp, q0)
    for i in range(3):
        if crease[i, 0] > 0.0:
            energy += _crease(X, v, opp, i, crease[i, 0], curl * crease[i, 1], want, gx, Hx,
                              hinge)
    return energy


#: :func:`_face` as a called function (not inlined): the Hessian and rounding kernels
#: share its one compiled body (inlined into each, the shell's kernels took 133 s to
#: compile, the first run of any fresh clone; the force kernel, the dynamic integrators'
#: inner loop, keeps it inlined: 30% faster)
_face_called = njit(cache=True, nogil=True, error_model="numpy")(_face.py_func)


@njit(cache=True, inline="always")
def _crease(X, v, opp, i, k, theta0, want, gx, Hx, hinge):
    """A crease across the edge opposite corner ``i`` (a fold too sharp for the patch
    quadratic: see :func:`pipeline.sim.terms.shell_stencil.creases`): a hinge of the
    edge's ends, ``q_i`` and the vertex across, ``k (1 - cos(theta - theta0))`` (the
    paper's Eq. 3 with discrete shells' weight in ``k``). Adds its gradient (and Hessian)
    to the face's rows; returns its energy."""
    hg, hH, hw = hinge
    a = (i + 1) % 3
    b = (i + 2) % 3
    cos_t, sin_t, ok = hinge_theta_derivatives(X, v[a], v[b], v[i], opp[i], hg, hH, hw)
    if not ok:
        return 0.0
    c0 = math.cos(theta0)
    s0 = math.sin(theta0)
    d1 = k * (sin_t * c0 - cos_t * s0)
    d2 = k * (cos_t * c0 + sin_t * s0)
    row = (a, b, i, 3 + i)
    for r in range(4):
        for x in range(3):
            gx[row[r], x] += d1 * hg[r, x]
    if want:
        for r in range(4):
            for q in range(4):
                for x in range(3):
                    for y in range(3):
                        Hx[row[r], row[q], x, y] += d2 * hg[r, x] * hg[q, y] + d1 * hH[r, q, x, y]
    return k * (1.0 - cos_t * c0 - sin_t * s0)


@njit(cache=True, inline="always")
def _bending_EPP(Ey, Eyy, EPP, Jy, Jy2, Dc, Sig, SD, Cb, real, Q11, Q12, Q22, det, sq, ddet,
                 opp, X, q0, e1, e2):
    """Add the bending part of d2E/dP2: ``Jy^T (Dc^T Sigma Dc + S) Jy`` (``Sigma = Hm^T Cb
    Hm``, S already in Eyy) and ``sum_y dE/dy d2y/dP2``."""
    # Sigma = Hm^T Cb Hm, Hm = [[0, 0, -2], [1, -1, -1], [0, -2, 0]]
    Hm = ((0.0, 0.0, -2.0), (1.0, -1.0, -1.0), (0.0, -2.0, 0.0))
    for r in range(3):
        for c in range(3):
            acc = 0.0
            for p in range(3):
                for q in range(3):
                    acc += Hm[p][r] * Cb[p, q] * Hm[q][c]
            Sig[r, c] = acc
    # Eyy += Dc^T Sig Dc
    for r in range(3):
        for y in range(9):
            SD[r, y] = Sig[r, 0] * Dc[0, y] + Sig[r, 1] * Dc[1, y] + Sig[r, 2] * Dc[2, y]
    for y in range(9):
        for z in range(9):
            Eyy[y, z] += Dc[0, y] * SD[0, z] + Dc[1, y] * SD[1, z] + Dc[2, y] * SD[2, z]
    # EPP += Jfull^T Eyy Jfull, Jfull[y] = metric part Jy[y] on P 0..2 and Jy2[y] on the
    # neighbour's own 3 primitives
    for i in range(3):
        if not real[i]:
            continue
        for j in range(3):
            if not real[j]:
                continue
            for r in range(3):
                for s_ in range(3):
                    e = Eyy[3 * i + r, 3 * j + s_]
                    if e == 0.0:
                        continue
                    for m in range(3):
                        jm = Jy[3 * i + r, m]
                        km = Jy2[3 * i + r, m]
                        for n in range(3):
                            jn = Jy[3 * j + s_, n]
                            kn = Jy2[3 * j + s_, n]
                            EPP[m, n] += jm * e * jn
                            EPP[m, 3 + 3 * j + n] += jm * e * kn
                            EPP[3 + 3 * i + m, n] += km * e * jn
                            EPP[3 + 3 * i + m, 3 + 3 * j + n] += km * e * kn
    # sum_y dE/dy d2y/dP2
    for i in range(3):
        if not real[i]:
            continue
        base = 3 + 3 * i
        # xi = Q s: d2xi[u, v] = -Q (B_v dxi_u + B_u dxi_v); with zeta = Q eta,
        # eta . d2xi[u, v] = -(zeta^T B_v dxi_u + zeta^T B_u dxi_v)
        eta1 = Ey[3 * i]
        eta2 = Ey[3 * i + 1]
        z1 = Q11 * eta1 + Q12 * eta2
        z2 = Q12 * eta1 + Q22 * eta2
        # dxi/dP for the 5 primitives (a11, a12, a22, s1, s2): columns of (Jy, Jy2)
        for u in range(5):
            if u < 3:
                xu1 = Jy[3 * i, u]
                xu2 = Jy[3 * i + 1, u]
                pu = u
            else:
                xu1 = Jy2[3 * i, u - 3]
                xu2 = Jy2[3 * i + 1, u - 3]
                pu = base + u - 3
            for m in range(3):  # v a metric entry: -zeta^T B_m dxi_u, both orders
                if m == 0:
                    t = z1 * xu1
                elif m == 1:
                    t = z1 * xu2 + z2 * xu1
                else:
                    t = z2 * xu2
                EPP[pu, m] -= t
                EPP[m, pu] -= t
        # w = tau / sqrt(det)
        om = Ey[3 * i + 2]
        o = opp[i]
        d = (X[o, 0] - q0[0], X[o, 1] - q0[1], X[o, 2] - q0[2])
        nvx = e1[1] * e2[2] - e1[2] * e2[1]
        nvy = e1[2] * e2[0] - e1[0] * e2[2]
        nvz = e1[0] * e2[1] - e1[1] * e2[0]
        wv = (nvx * d[0] + nvy * d[1] + nvz * d[2]) / sq
        for m in range(3):
            t = -0.5 * om * ddet[m] / (det * sq)
            EPP[base + 2, m] += t
            EPP[m, base + 2] += t
            for n in range(3):
                d2 = 0.0
                if (m == 0 and n == 2) or (m == 2 and n == 0):
                    d2 = 1.0
                elif m == 1 and n == 1:
                    d2 = -2.0
                EPP[m, n] += om * wv * (0.75 * ddet[m] * ddet[n] / (det * det) - 0.5 * d2 / det)


@njit(cache=True, inline="always")
def _primitive_jacobian(X, v, opp, real, e1, e2, J):
    """``J[m, A] = dP_m / dV_A`` (3-vectors): P = (a11, a12, a22, (s1, s2, tau) per
    neighbour), V = (e1, e2, d0, d1, d2)."""
    J[:, :, :] = 0.0
    n = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
         e1[0] * e2[1] - e1[1] * e2[0])
    q0 = (X[v[0], 0], X[v[0], 1], X[v[0], 2])
    for x in range(3):
        J[0, 0, x] = 2.0 * e1[x]
        J[1, 0, x] = e2[x]
        J[1, 1, x] = e1[x]
        J[2, 1, x] = 2.0 * e2[x]
    for i in range(3):
        if not real[i]:
            continue
        o = opp[i]
        d = (X[o, 0] - q0[0], X[o, 1] - q0[1], X[o, 2] - q0[2])
        m = 3 + 3 * i
        e2xd = (e2[1] * d[2] - e2[2] * d[1], e2[2] * d[0] - e2[0] * d[2],
                e2[0] * d[1] - e2[1] * d[0])
        dxe1 = (d[1] * e1[2] - d[2] * e1[1], d[2] * e1[0] - d[0] * e1[2],
                d[0] * e1[1] - d[1] * e1[0])
        for x in range(3):
            J[m, 0, x] = d[x]
            J[m, 2 + i, x] = e1[x]
            J[m + 1, 1, x] = d[x]
            J[m + 1, 2 + i, x] = e2[x]
            J[m + 2, 0, x] = e2xd[x]
            J[m + 2, 1, x] = dxe1[x]
            J[m + 2, 2 + i, x] = n[x]


@njit(cache=True, inline="always")
def _eps_matrix(M, A, B, s, v):
    """``M[A, B] += s E(v)``, ``E(v)_xy = eps_xyz v_z``, and ``M[B, A] -= s E(v)`` (its
    transpose)."""
    M[A, B, 0, 1] += s * v[2]
    M[A, B, 1, 0] -= s * v[2]
    M[A, B, 0, 2] -= s * v[1]
    M[A, B, 2, 0] += s * v[1]
    M[A, B, 1, 2] += s * v[0]
    M[A, B, 2, 1] -= s * v[0]
    M[B, A, 1, 0] += s * v[2]
    M[B, A, 0, 1] -= s * v[2]
    M[B, A, 2, 0] -= s * v[1]
    M[B, A, 0, 2] += s * v[1]
    M[B, A, 2, 1] += s * v[0]
    M[B, A, 1, 2] -= s * v[0]


@njit(cache=True, inline="always")
def _vertex_hessian(EP, EPP, J, Z, EVV, Hx, real, e1, e2, X, opp, q0):
    """``Hx`` = the face's Hessian over its 6 vertices, from ``d2E/dP2``, ``dE/dP`` and
    the primitives' derivatives (``J = dP/dV``: each row has at most 3 blocks)."""
    used = (True, True, real[0], real[1], real[2])
    # Z = EPP J, then EVV = J^T Z
    for m in range(12):
        for B in range(5):
            for y in range(3):
                Z[m, B, y] = 0.0
        for n in range(12):
            e = EPP[m, n]
            if e == 0.0:
                continue
            for B in range(5):
                if not used[B]:
                    continue
                Z[m, B, 0] += e * J[n, B, 0]
                Z[m, B, 1] += e * J[n, B, 1]
                Z[m, B, 2] += e * J[n, B, 2]
    for A in range(5):
        for B in range(5):
            for x in range(3):
                for y in range(3):
                    EVV[A, B, x, y] = 0.0
    for m in range(12):
        for A in range(5):
            if not used[A]:
                continue
            j0 = J[m, A, 0]
            j1 = J[m, A, 1]
            j2 = J[m, A, 2]
            if j0 == 0.0 and j1 == 0.0 and j2 == 0.0:
                continue
            for B in range(5):
                if not used[B]:
                    continue
                for y in range(3):
                    z = Z[m, B, y]
                    EVV[A, B, 0, y] += j0 * z
                    EVV[A, B, 1, y] += j1 * z
                    EVV[A, B, 2, y] += j2 * z
    # sum_m dE/dP_m d2P_m/dV2
    for x in range(3):
        EVV[0, 0, x, x] += 2.0 * EP[0]
        EVV[0, 1, x, x] += EP[1]
        EVV[1, 0, x, x] += EP[1]
        EVV[1, 1, x, x] += 2.0 * EP[2]
    for i in range(3):
        if not real[i]:
            continue
        m = 3 + 3 * i
        D = 2 + i
        for x in range(3):
            EVV[0, D, x, x] += EP[m]
            EVV[D, 0, x, x] += EP[m]
            EVV[1, D, x, x] += EP[m + 1]
            EVV[D, 1, x, x] += EP[m + 1]
        o = opp[i]
        d = (X[o, 0] - q0[0], X[o, 1] - q0[1], X[o, 2] - q0[2])
        t = EP[m + 2]
        # tau = det[e1, e2, d]: (e1, e2) E(d), (e2, d) E(e1), (d, e1) E(e2); transposes
        _eps_matrix(EVV, 0, 1, t, d)
        _eps_matrix(EVV, 1, D, t, e1)
        _eps_matrix(EVV, D, 0, t, e2)
    # to the vertices: q1 = e1, q2 = e2, o_i = d_i, q0 = -(the sum)
    for k in range(6):
        for l in range(6):
            for x in range(3):
                for y in range(3):
                    Hx[k, l, x, y] = 0.0
    for A in range(5):
        for B in range(5):
            for x in range(3):
                for y in range(3):
                    h = EVV[A, B, x, y]
                    Hx[A + 1, B + 1, x, y] = h
                    Hx[0, B + 1, x, y] -= h
                    Hx[A + 1, 0, x, y] -= h
                    Hx[0, 0, x, y] += h


@njit(cache=True, inline="always")
def _grown(f, face_edges, rest0, growth, A):
    """Squared grown rest lengths (Eq. 6) of the edges opposite q0, q1, q2 of face ``f``,
    and the determinant of its rest metric."""
    e0 = face_edges[f, 0]
    e1 = face_edges[f, 1]
    e2 = face_edges[f, 2]
    L0 = rest0[e0] * (1.0 + A * growth[e0])
    L1 = rest0[e1] * (1.0 + A * growth[e1])
    L2 = rest0[e2] * (1.0 + A * growth[e2])
    L0s = L0 * L0
    L1s = L1 * L1
    L2s = L2 * L2
    ab12 = 0.5 * (L2s + L1s - L0s)
    return L0s, L1s, L2s, L2s * L1s - ab12 * ab12


@njit(cache=True, inline="always")
def _face_rest(f, face_edges, rest0, growth, A, face_bbar, face_out, face_det0, curl, bbar):
    """Squared grown rest lengths of face ``f``'s edges, and its rest second fundamental
    form at growth A into ``bbar``: ``face_bbar - (1 - A) face_out`` (``face_bbar`` the
    form at A = 1, ``face_out`` its part the bud has not: zero but for an open start's
    model, :func:`pipeline.sim.terms.shell.bloom_form`), scaled by the face's linear growth ``(det abar(A) /
    det abar(0))^(1/4)`` (exactly 1 at A = 0) and by ``curl`` (``1 - B beta``)."""
    L0s, L1s, L2s, detb = _grown(f, face_edges, rest0, growth, A)
    k = curl
    if detb > 0.0 and face_det0[f] > 0.0 and detb != face_det0[f]:
        k *= math.sqrt(math.sqrt(detb / face_det0[f]))
    fade = 1.0 - A
    bbar[0] = k * (face_bbar[f, 0] - fade * face_out[f, 0])
    bbar[1] = k * (face_bbar[f, 1] - fade * face_out[f, 1])
    bbar[2] = k * (face_bbar[f, 2] - fade * face_out[f, 2])
    return L0s, L1s, L2s


@njit(cache=True, nogil=True)
def rest_dets(face_edges, rest0, growth, out):
    """``det abar`` of every face at growth 0, with the kernels' arithmetic."""
    for f in range(face_edges.shape[0]):
        out[f] = _grown(f, face_edges, rest0, growth, 0.0)[3]


@njit(cache=True, nogil=True, error_model="numpy")
def shell_forces(X, faces, opposite, ghost, crease, face_edges, rest0, growth, young, bend, nu,
                 face_bbar, face_out, face_det0, A, curl, F, scratch):
    """Add ``-dE/dX`` of every face (membrane and bending) to ``F``; return the energy.
    ``young``, ``bend``: per face (mesh units); ``curl``: ``1 - B(t) beta``."""
    s = scratch[:SCRATCH]
    G, Gi, Cs, Cb, bbar, hinge = _small(scratch)
    views = _views(s)
    gx = views[7]
    energy = 0.0
    for f in range(faces.shape[0]):
        L0s, L1s, L2s = _face_rest(f, face_edges, rest0, growth, A, face_bbar, face_out,
                                   face_det0, curl, bbar)
        v = faces[f]
        opp = opposite[f]
        energy += _face(X, v, opp, ghost[f], crease[f], L0s, L1s, L2s, young[f], nu, bend[f],
                        bbar, curl, False, views, G, Gi, Cs, Cb, hinge)
        for k in range(6):
            idx = v[k] if k < 3 else opp[k - 3]
            if idx < 0 or idx >= F.shape[0]:  # (no vertex, or a fixed anchor)
                continue
            F[idx, 0] -= gx[k, 0]
            F[idx, 1] -= gx[k, 1]
            F[idx, 2] -= gx[k, 2]
    return energy


@njit(cache=True, nogil=True, error_model="numpy")
def shell_hessian(X, faces, opposite, ghost, crease, face_edges, rest0, growth, young, bend, nu,
                  face_bbar, face_out, face_det0, A, curl, data, slots, rows, face_h, scratch):
    """Add every face's Hessian blocks to ``data``; ``slots[f, 6 r + c]`` is the block of
    the face's vertex pair (r, c) in the order q0, q1, q2, o0, o1, o2 (-1: no vertex).
    Each face's row sums of ``|H|`` go to ``face_h[rows[f]] (6,)``, for
    :func:`shell_rounding` (``rows``: the faces' indices in the whole)."""
    s = scratch[:SCRATCH]
    G, Gi, Cs, Cb, bbar, hinge = _small(scratch)
    views = _views(s)
    Hx = views[8]
    for f in range(faces.shape[0]):
        L0s, L1s, L2s = _face_rest(f, face_edges, rest0, growth, A, face_bbar, face_out,
                                   face_det0, curl, bbar)
        _face_called(X, faces[f], opposite[f], ghost[f], crease[f], L0s, L1s, L2s, young[f],
                     nu, bend[f], bbar, curl, True, views, G, Gi, Cs, Cb, hinge)
        for r in range(6):
            h = 0.0
            for c in range(6):
                slot = slots[f, 6 * r + c]
                for x in range(3):
                    for y in range(3):
                        h += abs(Hx[r, c, x, y])
                if slot < 0:
                    continue
                for x in range(3):
                    for y in range(3):
                        data[slot, x, y] += Hx[r, c, x, y]
            face_h[rows[f], r] = h


@njit(cache=True, nogil=True, error_model="numpy")
def shell_rounding(X, faces, opposite, ghost, crease, face_edges, rest0, growth, young, bend, nu,
                   face_bbar, face_out, face_det0, A, curl, full, rows, face_h, scale, scratch):
    """The size of what the force kernel adds and subtracts, per vertex into ``scale
    (V,)`` (force units), and for the energy (returned): ``eps`` times these bounds what
    rounding alone leaves in the gradient and the energy (see
    :func:`pipeline.sim.terms.elastic.rounding_scale`, the springs' own). Per face: the size
    of its gradient (its terms balance across faces at an equilibrium, not within one),
    and its Hessian times the coordinates' size (a representable X is ``eps |x|`` from
    the exact equilibrium). The Hessian's row sums ``|H|`` are ``face_h[rows[f]] (6,)``:
    taken here if ``full`` (each face's Hessian: ten times the force kernel's work), else
    those :func:`shell_hessian` left at its last assembly (a bound need not be of this
    very X). ``scale`` is added to (the caller zeroes it), so that pieces no face joins
    can each add theirs at once."""
    s = scratch[:SCRATCH]
    G, Gi, Cs, Cb, bbar, hinge = _small(scratch)
    views = _views(s)
    gx = views[7]
    Hx = views[8]
    energy = 0.0
    for f in range(faces.shape[0]):
        L0s, L1s, L2s = _face_rest(f, face_edges, rest0, growth, A, face_bbar, face_out,
                                   face_det0, curl, bbar)
        v = faces[f]
        opp = opposite[f]
        e = _face_called(X, v, opp, ghost[f], crease[f], L0s, L1s, L2s, young[f], nu, bend[f],
                         bbar, curl, full, views, G, Gi, Cs, Cb, hinge)
        if full:
            for k in range(6):
                h = 0.0
                for l in range(6):
                    for x in range(3):
                        for y in range(3):
                            h += abs(Hx[k, l, x, y])
                face_h[rows[f], k] = h
        size = 0.0
        for k in range(6):
            idx = v[k] if k < 3 else opp[k - 3]
            if idx >= 0:
                size = max(size, abs(X[idx, 0]), abs(X[idx, 1]), abs(X[idx, 2]))
        gsum = 0.0
        for k in range(6):
            idx = v[k] if k < 3 else opp[k - 3]
            if idx < 0 or idx >= scale.shape[0]:
                continue
            g = max(abs(gx[k, 0]), abs(gx[k, 1]), abs(gx[k, 2]))
            scale[idx] += g + face_h[rows[f], k] * size
            gsum += g
        energy += abs(e) + gsum * size
    return energy
