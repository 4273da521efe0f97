"""The two papers the lab's benches reproduce, cited once for the whole code (docs/physics.md).

The report's headings, the figures' captions and the findings' ``paper`` column all take their
citation from here.
"""
#: The PLPA paper: a pneumatic linear peristaltic actuator.
PLPA_CITATION = "Carneiro et al. 2020, Information 11(2):76"
#: The PLA paper: a conventional double-acting pneumatic cylinder.
PLA_CITATION = "Palomares et al. 2017, Mechatronics 45"


# -- the report's comparison with the papers ------------------------------------------------------------
# Values printed in the papers (docs/physics.md marks them *paper*), set beside the lab's in the
# report's tables (pipeline/serve/report/summaries.py).

#: PLPA (Carneiro et al. 2020), Table 2: the identified plant parameters: natural frequency
#: [rad/s], damping ratio [-], gain [m/(V s)].
PLPA_TABLE2 = {"wn_rad_s": 16.7, "zeta": 0.51, "k_lin_m_v_s": 0.82}
#: PLPA (Carneiro et al. 2020), Fig. 12: static breakaway force at 0 bar and at >= 1 bar
#: backpressure [N], their ratio [-] and the effect of the force rate (none) [N per N/s].
PLPA_FIG12 = {"mean_0bar_n": 10.0, "mean_ge1bar_n": 5.0, "ratio": 2.0, "rate_slope": 0.0}
#: PLPA (Carneiro et al. 2020), Fig. 15: the closed-loop 20 mm step under PID: overshoot [%],
#: settling time to the 2 % band [s], steady-state error [mm].
PLPA_FIG15 = {"overshoot_pct": 1.2, "settling_time_s": 4.0, "steady_state_error_mm": 0.0}
#: PLA (Palomares et al. 2017), Table 1: the spring model per chamber: polytropic index n [-],
#: effective area Ae [m2], Coulomb-like term epsilon [m2], structural damping delta [N/m].
PLA_TABLE1 = {"front": {"n_polytropic": 1.123, "ae_m2": 1.541e-3, "epsilon_m2": 2.143e-5, "delta_n_m": 3.509e3},
              "rear": {"n_polytropic": 1.063, "ae_m2": 1.795e-3, "epsilon_m2": 2.136e-5, "delta_n_m": 2.963e3}}
#: PLA (Palomares et al. 2017), Table 2: pressure dynamics (Eq. 11) per step direction: natural
#: frequency [rad/s], damping ratio [-].
PLA_TABLE2 = {"charge": {"wn_rad_s": 52.0, "zeta": 1.00}, "discharge": {"wn_rad_s": 52.0, "zeta": 0.69}}
#: PLA (Palomares et al. 2017), Table 3: the smallest and the largest NRMSE of the spring model
#: over the 120 tests [%].
PLA_TABLE3_NRMSE_MIN_PCT = 1.16
PLA_TABLE3_NRMSE_MAX_PCT = 2.39
#: (Table 3's bound on every test's NRMSE: :data:`PLA_NRMSE_LIMIT_PCT`, below.)
# -- findings and analyses -----------------------------------------------------------------------------
#: PLPA paper, section 3.1 (Figs. 9-10): the rollers' spring force at 100 % (settings 33 %, 66 %,
#: 100 % of it). [N]
PLPA_SPRING_FORCE_MAX_N = 1300.0
#: PLPA paper, section 3.2.1 (Fig. 12): the breakaway force at 0 bar backpressure is "about twice"
#: that at >= 1 bar, read as a ratio of the means within this band. [-]
PLPA_BREAKAWAY_RATIO_BAND = (1.5, 2.5)
#: PLA paper, Table 3: the fitted models reproduce every test with NRMSE below this (1.16-2.39 %):
#: the findings' criterion and the limit the analyses hold a model fit to. [%]
PLA_NRMSE_LIMIT_PCT = 2.5
