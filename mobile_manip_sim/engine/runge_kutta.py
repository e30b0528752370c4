"""Embedded explicit Runge–Kutta pairs with error control and dense output, compiled.

Two methods, both with local extrapolation (the step is taken with the higher-order formula):

- ``rk45``: Dormand–Prince 5(4), 6 stages + the FSAL stage f(y₁) (Dormand & Prince 1980;
  Hairer–Nørsett–Wanner, *Solving ODEs I*, §II.5, Table 5.2). Dense output: Shampine's
  4th-order interpolant (Shampine 1986, the optimal c₆ choice), the one SciPy's RK45 uses.
- ``dop853``: Dormand–Prince 8(5,3), 12 stages + f(y₁) (Hairer–Nørsett–Wanner §II.5 and the
  Fortran code DOP853). The error estimate combines the 5th- and 3rd-order embedded formulas as
  Hairer's code does (`error_norm`). Dense output: the 7th-order interpolant, which costs 3 more
  stages per step that needs it (`dense_prepare`), or — where its estimated error is within
  the tolerance — a 6th-order continuous extension from the step's own stages, which costs none
  (`dense_from_stages`). f(y₁) enters neither error estimate, so a rejected step does not
  evaluate it (11 right-hand sides, as in dop853.f; an accepted one 12).

The right-hand side is `engine.system.derivative(system, s, ds)` of the state s = (q, u, e, W)
(n = n_q + n_u + 1 entries; autonomous: efforts are held between calls, so no t argument).
Time is in seconds, h is the step (s); tolerances are per component of s, in its own units.

Every function writes into arrays the caller owns and allocates nothing, so an engine loop can
run them back to back in compiled code. Shapes (n = len(s)):

- ``K``      (MAX_STAGES, n)  stage derivatives k_i = f(y₀ + h Σ_j a_ij k_j); row `n_stages`
                              is f(y₁); DOP853's rows 13..15 are the dense-output stages.
- ``err``    (2, n)           h·Σ e_i k_i for the main embedded estimate (row 0) and, for
                              DOP853, the 3rd-order one (row 1; unused by rk45).
- ``coeffs`` (MAX_DENSE, n)   the interpolant of the last step (`dense_prepare`).

Step-size control follows Hairer/SciPy: ‖err‖ < 1 accepts; h_new = h·min(MAX_FACTOR,
SAFETY·‖err‖^(−1/(p̂+1))) after an accepted step (not growing right after a rejection),
h·max(MIN_FACTOR, SAFETY·‖err‖^(−1/(p̂+1))) after a rejected one, p̂ the error estimator order.
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from ..dynamics.jit import jit
from ..methods import IDS
from .system import derivative

RK45, DOP853 = IDS["rk45"], IDS["dop853"]

SAFETY = 0.9        # of the asymptotically optimal step
MIN_FACTOR = 0.2    # the most a step can shrink after a rejection
MAX_FACTOR = 10.0   # the most a step can grow after an acceptance

MAX_STAGES = 16     # rows of K: DOP853's 12 stages, f(y₁) and 3 dense-output stages
MAX_DENSE = 7       # rows of the dense-output coefficients (DOP853's degree-7 interpolant)
# rows of the work array of a solve (`accepted_step`, `adaptive_stepping.Solve`): K, coeffs, f₀,
# f₁, y₁, err (2)
WORK_K, WORK_COEFFS, WORK_F0, WORK_F1, WORK_Y1, WORK_ERR = 0, 16, 23, 24, 25, 26
WORK_ROWS = 28

Tableau = namedtuple("Tableau", [
    "order",         # order of the propagated solution
    "error_order",   # order p̂ of the error estimator (error ∝ h^(p̂+1))
    "n_stages",      # stages per step, f(y₀) included, f(y₁) not (it is the next step's f₀)
    "n_extended",    # rows of A: stages, the f(y₁) row, extra dense-output stages
    "fsal",          # f(y₁) is the next step's first stage
    "dense_order",   # order of the dense output
    "A",             # (n_extended, n_extended) stage coefficients a_ij (row n_stages = b)
    "B",             # (n_stages,) weights b_i of the propagated solution
    "C",             # (n_extended,) nodes c_i
    "E",             # (2, n_stages + 1) error weights: row 0 main estimate, row 1 DOP853's 3rd order
    "P",             # dense output: rk45 (7, 4) Q = Kᵀ P; dop853 (4, 16) D of the degree-3..6 terms
    "F",             # dop853: (7, 13) the F₀..F₆ (over h) of the stage-only continuous extension
                     # (`dense_from_stages`) as weights of k₀..k₁₂; rk45: unused
    "F_check",       # dop853: (13,) weights of its error estimate at θ = 1/2; rk45: unused
])


def _rk45() -> Tableau:
    """Dormand–Prince 5(4) (HNW I, Table II.5.2) and Shampine's dense output weights."""
    A = np.zeros((7, 7))
    A[1, :1] = [1 / 5]
    A[2, :2] = [3 / 40, 9 / 40]
    A[3, :3] = [44 / 45, -56 / 15, 32 / 9]
    A[4, :4] = [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729]
    A[5, :5] = [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656]
    B = np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84])
    A[6, :6] = B
    C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0])
    E = np.zeros((2, 7))
    # b − b̂, b̂ the 4th-order weights (71/57600, 0, −71/16695, 71/1920, −17253/339200, 22/525, −1/40)
    E[0] = [-71 / 57600, 0.0, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40]
    P = np.array([
        [1.0, -8048581381 / 2820520608, 8663915743 / 2820520608, -12715105075 / 11282082432],
        [0.0, 0.0, 0.0, 0.0],
        [0.0, 131558114200 / 32700410799, -68118460800 / 10900136933, 87487479700 / 32700410799],
        [0.0, -1754552775 / 470086768, 14199869525 / 1410260304, -10690763975 / 1880347072],
        [0.0, 127303824393 / 49829197408, -318862633887 / 49829197408, 701980252875 / 199316789632],
        [0.0, -282668133 / 205662961, 2019193451 / 616988883, -1453857185 / 822651844],
        [0.0, 40617522 / 29380423, -110615467 / 29380423, 69997945 / 29380423]])
    return Tableau(5, 4, 6, 7, True, 4, A, B, C, E, P, np.zeros((7, 7)), np.zeros(7))


# DOP853 (Hairer's DOP853 Fortran code, dop853.f): the nonzero a_ij by row, 0-based stages.
_DOP853_A = {
    1: {0: 5.26001519587677318785587544488e-2},
    2: {0: 1.97250569845378994544595329183e-2, 1: 5.91751709536136983633785987549e-2},
    3: {0: 2.95875854768068491816892993775e-2, 2: 8.87627564304205475450678981324e-2},
    4: {0: 2.41365134159266685502369798665e-1, 2: -8.84549479328286085344864962717e-1,
        3: 9.24834003261792003115737966543e-1},
    5: {0: 3.7037037037037037037037037037e-2, 3: 1.70828608729473871279604482173e-1,
        4: 1.25467687566822425016691814123e-1},
    6: {0: 3.7109375e-2, 3: 1.70252211019544039314978060272e-1,
        4: 6.02165389804559606850219397283e-2, 5: -1.7578125e-2},
    7: {0: 3.70920001185047927108779319836e-2, 3: 1.70383925712239993810214054705e-1,
        4: 1.07262030446373284651809199168e-1, 5: -1.53194377486244017527936158236e-2,
        6: 8.27378916381402288758473766002e-3},
    8: {0: 6.24110958716075717114429577812e-1, 3: -3.36089262944694129406857109825,
        4: -8.68219346841726006818189891453e-1, 5: 2.75920996994467083049415600797e1,
        6: 2.01540675504778934086186788979e1, 7: -4.34898841810699588477366255144e1},
    9: {0: 4.77662536438264365890433908527e-1, 3: -2.48811461997166764192642586468,
        4: -5.90290826836842996371446475743e-1, 5: 2.12300514481811942347288949897e1,
        6: 1.52792336328824235832596922938e1, 7: -3.32882109689848629194453265587e1,
        8: -2.03312017085086261358222928593e-2},
    10: {0: -9.3714243008598732571704021658e-1, 3: 5.18637242884406370830023853209,
         4: 1.09143734899672957818500254654, 5: -8.14978701074692612513997267357,
         6: -1.85200656599969598641566180701e1, 7: 2.27394870993505042818970056734e1,
         8: 2.49360555267965238987089396762, 9: -3.0467644718982195003823669022},
    11: {0: 2.27331014751653820792359768449, 3: -1.05344954667372501984066689879e1,
         4: -2.00087205822486249909675718444, 5: -1.79589318631187989172765950534e1,
         6: 2.79488845294199600508499808837e1, 7: -2.85899827713502369474065508674,
         8: -8.87285693353062954433549289258, 9: 1.23605671757943030647266201528e1,
         10: 6.43392746015763530355970484046e-1},
    # row 12: the weights b_i of the 8th-order solution (f(y₁) is stage 12)
    12: {0: 5.42937341165687622380535766363e-2, 5: 4.45031289275240888144113950566,
         6: 1.89151789931450038304281599044, 7: -5.8012039600105847814672114227,
         8: 3.1116436695781989440891606237e-1, 9: -1.52160949662516078556178806805e-1,
         10: 2.01365400804030348374776537501e-1, 11: 4.47106157277725905176885569043e-2},
    # rows 13..15: the three stages of the dense output
    13: {0: 5.61675022830479523392909219681e-2, 6: 2.53500210216624811088794765333e-1,
         7: -2.46239037470802489917441475441e-1, 8: -1.24191423263816360469010140626e-1,
         9: 1.5329179827876569731206322685e-1, 10: 8.20105229563468988491666602057e-3,
         11: 7.56789766054569976138603589584e-3, 12: -8.298e-3},
    14: {0: 3.18346481635021405060768473261e-2, 5: 2.83009096723667755288322961402e-2,
         6: 5.35419883074385676223797384372e-2, 7: -5.49237485713909884646569340306e-2,
         10: -1.08347328697249322858509316994e-4, 11: 3.82571090835658412954920192323e-4,
         12: -3.40465008687404560802977114492e-4, 13: 1.41312443674632500278074618366e-1},
    15: {0: -4.28896301583791923408573538692e-1, 5: -4.69762141536116384314449447206,
         6: 7.68342119606259904184240953878, 7: 4.06898981839711007970213554331,
         8: 3.56727187455281109270669543021e-1, 12: -1.39902416515901462129418009734e-3,
         13: 2.9475147891527723389556272149, 14: -9.15095847217987001081870187138},
}
_DOP853_C = [0.0, 0.526001519587677318785587544488e-01, 0.789002279381515978178381316732e-01,
             0.118350341907227396726757197510, 0.281649658092772603273242802490,
             1 / 3, 0.25, 4 / 13, 127 / 195, 0.6, 6 / 7, 1.0, 1.0, 0.1, 0.2, 7 / 9]
# b − b̂ of the 3rd-order formula: b̂ differs from b at stages 0, 8, 11 (bhh1..bhh3 of dop853.f)
_DOP853_BHH = {0: 0.244094488188976377952755905512, 8: 0.733846688281611857341361741547,
               11: 0.220588235294117647058823529412e-1}
# the 5th-order error weights er1..er12 of dop853.f
_DOP853_ER = {0: 0.1312004499419488073250102996e-1, 5: -0.1225156446376204440720569753e+1,
              6: -0.4957589496572501915214079952, 7: 0.1664377182454986536961530415e+1,
              8: -0.3503288487499736816886487290, 9: 0.3341791187130174790297318841,
              10: 0.8192320648511571246570742613e-1, 11: -0.2235530786388629525884427845e-1}
# d4j..d7j of dop853.f: the degree-3..6 terms of the interpolant, by stage
_DOP853_D = [
    {0: -0.84289382761090128651353491142e+1, 5: 0.56671495351937776962531783590,
     6: -0.30689499459498916912797304727e+1, 7: 0.23846676565120698287728149680e+1,
     8: 0.21170345824450282767155149946e+1, 9: -0.87139158377797299206789907490,
     10: 0.22404374302607882758541771650e+1, 11: 0.63157877876946881815570249290,
     12: -0.88990336451333310820698117400e-1, 13: 0.18148505520854727256656404962e+2,
     14: -0.91946323924783554000451984436e+1, 15: -0.44360363875948939664310572000e+1},
    {0: 0.10427508642579134603413151009e+2, 5: 0.24228349177525818288430175319e+3,
     6: 0.16520045171727028198505394887e+3, 7: -0.37454675472269020279518312152e+3,
     8: -0.22113666853125306036270938578e+2, 9: 0.77334326684722638389603898808e+1,
     10: -0.30674084731089398182061213626e+2, 11: -0.93321305264302278729567221706e+1,
     12: 0.15697238121770843886131091075e+2, 13: -0.31139403219565177677282850411e+2,
     14: -0.93529243588444783865713862664e+1, 15: 0.35816841486394083752465898540e+2},
    {0: 0.19985053242002433820987653617e+2, 5: -0.38703730874935176555105901742e+3,
     6: -0.18917813819516756882830838328e+3, 7: 0.52780815920542364900561016686e+3,
     8: -0.11573902539959630126141871134e+2, 9: 0.68812326946963000169666922661e+1,
     10: -0.10006050966910838403183860980e+1, 11: 0.77771377980534432092869265740,
     12: -0.27782057523535084065932004339e+1, 13: -0.60196695231264120758267380846e+2,
     14: 0.84320405506677161018159903784e+2, 15: 0.11992291136182789328035130030e+2},
    {0: -0.25693933462703749003312586129e+2, 5: -0.15418974869023643374053993627e+3,
     6: -0.23152937917604549567536039109e+3, 7: 0.35763911791061412378285349910e+3,
     8: 0.93405324183624310003907691704e+2, 9: -0.37458323136451633156875139351e+2,
     10: 0.10409964950896230045147246184e+3, 11: 0.29840293426660503123344363579e+2,
     12: -0.43533456590011143754432175058e+2, 13: 0.96324553959188282948394950600e+2,
     14: -0.39177261675615439165231486172e+2, 15: -0.14972683625798562581422125276e+3},
]

# dop853's stage-only continuous extension (`dense_from_stages`), as `continuous_extension.py`
# derives it (test_runge_kutta checks its order conditions): the F₀..F₆ (over h) as weights of
# k₀..k₁₂, and the weights at θ = 1/2 of the difference of the 6th- and 5th-order extensions
# (its error estimate). Written out: deriving them costs a least-squares solve at every import.
_DOP853_FREE_F = [
    [0.05429373411600169, -5.999643229086785e-13, -6.076735304329663e-13, -6.186763605799311e-13, -6.519945399591063e-13, 4.450312892751709, 1.8915178993145187, -5.8012039600084115, 0.3111643669571678, -0.15216094966355484, 0.20136540080373866, 0.0447106157278497, 7.824506884770887e-14],
    [0.9457067282012801, -1.4192444537261621e-11, 4.178466765024116e-11, 1.6796176457123037e-11, 3.59444847781183e-12, -4.450438417097075, -1.891556640808659, 5.801362041647565, -0.3111775405104513, 0.15217934425687218, -0.2013649000063047, -0.044710615731416326, 3.928857239543504e-12],
    [-0.8914129940855986, 1.3341068531123429e-11, -4.264838989472531e-11, -1.7677825517831415e-11, -4.537128005935306e-12, 8.900751309857696, 3.7830745401274726, -11.602566001649848, 0.622341907467785, -0.30434029391733475, 0.40273030080973715, 0.08942123145900993, -1.0000000000041136],
    [-5.267322117393796, -4.5468278695795225e-11, 1.0525535373112949e-11, -4.8559487705782816e-11, 6.211023834464558e-12, 329.38400484061276, 142.91731342341245, -458.20921914850805, 11.62154704578495, -20.641869487394615, -0.5888866163063966, 1.1177653932014522, -0.3333333333409225],
    [6.162266097478138, -1.2203095094211109e-10, 7.670660951192623e-10, -2.768304354534471e-10, 7.320746469289017e-11, -969.2582686798651, -321.8981680777488, 1241.245765199932, -102.53806793224635, 145.568179115146, -2.526014002012758, -3.7556917211218646, 6.999999999987763],
    [10.254628247795509, 3.462450012496778e-11, -3.2084535865801794e-10, 6.539165054311547e-10, -2.416144618861922e-11, -1321.5945295184429, -513.189242006863, 1793.4170287688448, -47.19913776605608, 73.85370557892838, 7.151358726432974, 0.41729908007150013, -3.1111111110508607],
    [-15.837046447230838, 2.0481082521096706e-10, 3.947526939662777e-10, -4.957895846900797e-10, -7.236673290677164e-11, 4299.827774810385, 1327.082159432855, -5415.071096374426, 451.26118827195984, -630.108050996666, -17.15492869691379, -6.118592689106812e-11, 6.814062470590961e-11],
]
_DOP853_FREE_CHECK = [-0.07842698858350779, -5.9982267951950615e-12, 2.922871319904704e-11, 5.842306999535331e-13, 1.3411642910087046e-12, 21.293272472195255, 6.5718729838004215, -26.81609364834476, 2.2347005395095105, -3.1203720562180663, -0.08495330206965176, -3.6665962285633294e-10, 5.227626155366639e-11]


def _dop853() -> Tableau:
    """DOP853 from the sparse rows above."""
    A = np.zeros((16, 16))
    for i, row in _DOP853_A.items():
        for j, a in row.items():
            A[i, j] = a
    B = A[12, :12].copy()
    E = np.zeros((2, 13))
    for j, e in _DOP853_ER.items():
        E[0, j] = e
    E[1, :12] = B
    for j, bhh in _DOP853_BHH.items():
        E[1, j] -= bhh
    P = np.zeros((4, 16))
    for r, row in enumerate(_DOP853_D):
        for j, d in row.items():
            P[r, j] = d
    return Tableau(8, 7, 12, 16, True, 7, A, B, np.array(_DOP853_C), E, P,
                   np.array(_DOP853_FREE_F), np.array(_DOP853_FREE_CHECK))


RK45_TABLEAU = _rk45()
DOP853_TABLEAU = _dop853()
# For Python callers: compiled functions hand no arrays of their own back to Python (they run
# without reference counting, `dynamics/jit.py`), so `tableau` is for compiled code only.
TABLEAUS = {RK45: RK45_TABLEAU, DOP853: DOP853_TABLEAU}


@jit
def tableau(method_id):
    """The Tableau of a method id (RK45 or DOP853)."""
    if method_id == RK45:
        return RK45_TABLEAU
    return DOP853_TABLEAU


def work_array(n: int) -> np.ndarray:
    """Scratch for `accepted_step` with states of n entries: (WORK_ROWS, n)."""
    return np.zeros((WORK_ROWS, n))


@jit
def _stage_state(s, h, a, n_terms, K, y):
    """y = s + h Σ_{j < n_terms} a_j k_j (the state at which a stage is evaluated)."""
    for i in range(s.shape[0]):
        total = 0.0
        for j in range(n_terms):
            if a[j] != 0.0:
                total += a[j] * K[j, i]
        y[i] = s[i] + h * total


@jit
def _stages(method_id, system, s, f0, h, out, K):
    """The stages k₁..k_{n_stages−1} of a step of length h from s (k₀ = f0) into K, and its
    end state y₁ into out (which doubles as the stage-state scratch: it must not alias s)."""
    tab = tableau(method_id)
    n_stages = tab.n_stages
    for i in range(s.shape[0]):
        K[0, i] = f0[i]
    for stage in range(1, n_stages):
        _stage_state(s, h, tab.A[stage], stage, K, out)
        derivative(system, out, K[stage])
    _stage_state(s, h, tab.B, n_stages, K, out)


@jit
def _end_derivative(method_id, system, out, f_out, K):
    """f(y₁) into f_out and K[n_stages]."""
    n_stages = tableau(method_id).n_stages
    derivative(system, out, f_out)
    for i in range(out.shape[0]):
        K[n_stages, i] = f_out[i]


@jit
def _error_estimates(method_id, h, K, err):
    """err[row] = h·Σ_j E[row, j] k_j."""
    tab = tableau(method_id)
    for row in range(2):
        for i in range(err.shape[1]):
            total = 0.0
            for j in range(tab.n_stages + 1):
                if tab.E[row, j] != 0.0:
                    total += tab.E[row, j] * K[j, i]
            err[row, i] = h * total


@jit
def error_needs_end_derivative(method_id):
    """Whether f(y₁) enters the error estimate (rk45: it is a stage; dop853: not)."""
    tab = tableau(method_id)
    return tab.E[0, tab.n_stages] != 0.0 or tab.E[1, tab.n_stages] != 0.0


@jit
def rk_step(method_id, system, s, f0, h, out, f_out, K, err):
    """One step of length h (s) from s, f0 = f(s): out = y₁, f_out = f(y₁).

    Writes the stage derivatives into K[:n_stages + 1] (row n_stages = f(y₁)) and the error
    estimates into err (see the module docstring). `out` doubles as the stage-state scratch, so
    it must not alias s. Returns the number of right-hand sides evaluated (n_stages: the stages
    after the first, plus f(y₁)).
    """
    _stages(method_id, system, s, f0, h, out, K)
    _end_derivative(method_id, system, out, f_out, K)
    _error_estimates(method_id, h, K, err)
    return tableau(method_id).n_stages


@jit
def error_norm(method_id, err, s, out, rtol, atol):
    """Hairer's scaled error norm of a step s → out, with sc_i = atol + rtol·max(|s_i|, |out_i|).

    rk45: the RMS of err[0]/sc. dop853 (as dop853.f): with e5 = Σ(err[0]/sc)², e3 = Σ(err[1]/sc)²,
    ‖err‖ = e5 / √(n (e5 + 0.01 e3)) — the 5th-order estimate, damped by the 3rd-order one
    where that is small. A step is accepted when the norm is below 1.
    """
    n = s.shape[0]
    e5 = 0.0
    e3 = 0.0
    for i in range(n):
        sc = atol + rtol * max(abs(s[i]), abs(out[i]))
        e5 += (err[0, i] / sc) ** 2
        e3 += (err[1, i] / sc) ** 2
    if method_id == RK45:
        return math.sqrt(e5 / n)
    if e5 == 0.0 and e3 == 0.0:
        return 0.0
    return e5 / math.sqrt(n * (e5 + 0.01 * e3))


@jit
def next_step(method_id, err_norm, h, previous_rejected):
    """The next step size after a step of size h with error norm err_norm (same sign as h).

    Accepted (err_norm < 1): h·min(MAX_FACTOR, SAFETY·err_norm^(−1/(p̂+1))), capped at h when
    this step was itself retried after a rejection (`previous_rejected`). Rejected: h·max(MIN_FACTOR,
    SAFETY·err_norm^(−1/(p̂+1))), the step to retry with.
    """
    exponent = -1.0 / (tableau(method_id).error_order + 1)
    if err_norm < 1.0:
        if err_norm == 0.0:
            factor = MAX_FACTOR
        else:
            factor = min(MAX_FACTOR, SAFETY * err_norm ** exponent)
        if previous_rejected:
            factor = min(1.0, factor)
    else:
        factor = SAFETY * err_norm ** exponent
        if not factor > MIN_FACTOR:   # also when err_norm is NaN
            factor = MIN_FACTOR
    return h * factor


@jit
def _scaled_rms(x, s, rtol, atol):
    """‖x/sc‖ (RMS) with sc_i = atol + rtol|s_i|."""
    total = 0.0
    for i in range(x.shape[0]):
        total += (x[i] / (atol + rtol * abs(s[i]))) ** 2
    return math.sqrt(total / x.shape[0])


@jit
def initial_step(method_id, system, s, f0, span, rtol, atol, max_step, y_scratch, f_scratch):
    """A starting step (s), Hairer's heuristic (HNW I §II.4; SciPy's select_initial_step).

    With sc = atol + rtol|s|, d0 = ‖s/sc‖, d1 = ‖f0/sc‖ (RMS norms): h0 = 0.01 d0/d1 (1e-6 if
    either is below 1e-5); one explicit Euler step gives d2 = ‖(f(s + h0 f0) − f0)/sc‖/h0, and
    h1 = (0.01/max(d1, d2))^(1/(p̂+1)). Returns min(100 h0, h1, span, max_step) for a run over
    `span` seconds. Costs one right-hand side, evaluated at y_scratch into f_scratch.
    """
    n = s.shape[0]
    if span == 0.0:
        return 0.0
    d0 = _scaled_rms(s, s, rtol, atol)
    d1 = _scaled_rms(f0, s, rtol, atol)
    if d0 < 1e-5 or d1 < 1e-5:
        h0 = 1e-6
    else:
        h0 = 0.01 * d0 / d1
    h0 = min(h0, span)
    for i in range(n):
        y_scratch[i] = s[i] + h0 * f0[i]
    derivative(system, y_scratch, f_scratch)
    for i in range(n):
        f_scratch[i] -= f0[i]
    d2 = _scaled_rms(f_scratch, s, rtol, atol) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1.0 / (tableau(method_id).error_order + 1))
    return min(100.0 * h0, h1, span, max_step)


@jit
def dense_prepare(method_id, system, s, out, f0, f1, h, K, coeffs):
    """The interpolant of the step s → out of length h, from its stages K (after `rk_step`).

    f0 = f(s) and f1 = f(out). rk45 writes coeffs[:4] = Q with Q_j = Σ_i P_ij k_i (state/s);
    dop853 evaluates its 3 dense-output stages into K[13:16] and writes coeffs[:7] = the
    F₀..F₆ of dop853.f (in state units: F₀ = Δy, F₁ = h f0 − Δy, F₂ = 2Δy − h(f0 + f1),
    F₃₊ᵣ = h Σ_i d_ri k_i). coeffs[0] serves as stage-state scratch first. Returns the number
    of right-hand sides evaluated (0 or 3).
    """
    tab = tableau(method_id)
    n = s.shape[0]
    if method_id == RK45:
        for j in range(4):
            for i in range(n):
                total = 0.0
                for k in range(tab.n_stages + 1):
                    total += K[k, i] * tab.P[k, j]
                coeffs[j, i] = total
        return 0
    for stage in range(tab.n_stages + 1, tab.n_extended):
        _stage_state(s, h, tab.A[stage], stage, K, coeffs[0])
        derivative(system, coeffs[0], K[stage])
    for i in range(n):
        dy = out[i] - s[i]
        coeffs[0, i] = dy
        coeffs[1, i] = h * f0[i] - dy
        coeffs[2, i] = 2.0 * dy - h * (f1[i] + f0[i])
    for r in range(4):
        for i in range(n):
            total = 0.0
            for k in range(tab.n_extended):
                if tab.P[r, k] != 0.0:
                    total += tab.P[r, k] * K[k, i]
            coeffs[3 + r, i] = h * total
    return tab.n_extended - tab.n_stages - 1


@jit
def dense_from_stages(method_id, s, out, h, K, coeffs, rtol, atol):
    """dop853: the interpolant of the step s → out of length h from its 13 stages alone (no
    right-hand side), when its estimated error is within the tolerance. Returns True when
    coeffs[:7] holds it (the F₀..F₆ that `dense_eval` reads), False (coeffs untouched) when the
    step needs `dense_prepare`'s 7th-order interpolant; always False for rk45, whose
    interpolant costs nothing anyway.

    The continuous extension is of order 6 (`continuous_extension.py`: one order below the
    7th-order one, whose 3 extra stages it saves). Its error is estimated at θ = 1/2 by its difference to
    the 5th-order extension of the same stages (tab.F_check), in `error_norm`'s scaled RMS norm,
    which must not exceed 1: as the step's error is estimated by lower-order formulas, the
    estimate is that of the lower-order extension, so it bounds the 6th-order one's
    (measured: 1.2-2× its error on the paper robot). The estimate shrinks with h like h⁶
    where the step's own error shrinks like h⁸, so loose tolerances (long steps) pass and
    tight ones fall back.
    """
    if method_id == RK45:
        return False
    tab = tableau(method_id)
    n = s.shape[0]
    total = 0.0
    for i in range(n):
        estimate = 0.0
        for k in range(tab.n_stages + 1):
            estimate += tab.F_check[k] * K[k, i]
        sc = atol + rtol * max(abs(s[i]), abs(out[i]))
        total += (h * estimate / sc) ** 2
    if not math.sqrt(total / n) <= 1.0:   # also when NaN
        return False
    for r in range(7):
        for i in range(n):
            value = 0.0
            for k in range(tab.n_stages + 1):
                value += tab.F[r, k] * K[k, i]
            coeffs[r, i] = h * value
    return True


@jit
def dense_eval(method_id, coeffs, s, h, theta, y_out):
    """The state at t₀ + θh, θ ∈ [0, 1], of the step prepared by `dense_prepare` from s.

    rk45: y = s + h Σ_{j<4} θ^(j+1) Q_j. dop853: y = s + θ(F₀ + (1−θ)(F₁ + θ(F₂ + (1−θ)(F₃
    + θ(F₄ + (1−θ)(F₅ + θF₆)))))) (h is already inside the F's).
    """
    n = s.shape[0]
    if method_id == RK45:
        for i in range(n):
            y_out[i] = 0.0
        power = 1.0
        for j in range(4):
            power *= theta
            for i in range(n):
                y_out[i] += coeffs[j, i] * power
        for i in range(n):
            y_out[i] = h * y_out[i] + s[i]
        return
    for i in range(n):
        y = 0.0
        for r in range(6, -1, -1):
            y += coeffs[r, i]
            y *= theta if (6 - r) % 2 == 0 else 1.0 - theta
        y_out[i] = y + s[i]


@jit
def accepted_step(method_id, system, s, t, h_abs, t_bound, rtol, atol, work):
    """Steps from (t, s) with f(s) in work[WORK_F0], shrinking h until one is accepted: the new
    state and its f in work[WORK_Y1], work[WORK_F1] (f(y₁) evaluated last), the stages in
    work[WORK_K…]. Returns (h
    taken, next h to try); h taken = −1 when the step fell below 10 ulps of t (s unchanged)."""
    K = work[WORK_K:WORK_K + MAX_STAGES]
    f0, f1, y1 = work[WORK_F0], work[WORK_F1], work[WORK_Y1]
    err = work[WORK_ERR:WORK_ERR + 2]
    min_step = 10.0 * abs(np.nextafter(t, np.inf) - t)
    retried = False
    while True:
        if h_abs < min_step:
            return -1.0, h_abs
        t_new = min(t + h_abs, t_bound)
        h = t_new - t
        # f(y₁) only once it is needed: a rejected dop853 step costs 11 right-hand sides, not 12
        end_first = error_needs_end_derivative(method_id)
        _stages(method_id, system, s, f0, h, y1, K)
        if end_first:
            _end_derivative(method_id, system, y1, f1, K)
        _error_estimates(method_id, h, K, err)
        norm = error_norm(method_id, err, s, y1, rtol, atol)
        h_next = next_step(method_id, norm, abs(h), retried)
        if norm < 1.0:
            if not end_first:
                _end_derivative(method_id, system, y1, f1, K)
            return h, h_next
        h_abs = h_next
        retried = True
