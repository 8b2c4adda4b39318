/*
 * bywire VW Passat plant: FMI 2.0 Co-Simulation FMU.
 *
 * Longitudinal: point mass with a lagged drive force (force and power limited, its direction
 * set by the gear input: +1 drive, -1 reverse), a lagged
 * brake pressure, aerodynamic drag with head wind, rolling resistance and road grade.
 * Brakes and rolling resistance act as Coulomb friction with stiction: at standstill they
 * hold the car while they exceed the other forces, so the car neither creeps nor chatters
 * and its speed never flips sign at v = 0.
 *
 * Lateral: single-track model. Below v_kinematic_max_mps the kinematic bicycle (no slip),
 * above v_dynamic_min_mps the dynamic bicycle with linear tyres, and in between the two
 * outputs blended linearly in speed. The dynamic states are slaved to the kinematic values
 * while the blend weight is zero, so every output is continuous across the switch.
 * Reversing always uses the kinematic model (the linear tyre model assumes forward travel).
 *
 * Integration: explicit Euler with a fixed internal step (step_s, 1 ms by default); a
 * communication step is split into ceil(h / step_s) equal sub-steps. Actuator lags use the
 * exact first-order discretisation so any time constant >= 0 is stable.
 *
 * Deviations from a full vehicle model (see README.md): longitudinal and lateral motion are
 * decoupled (no cornering drag, no vy*r term), no gear ratios (the gear input only sets the
 * drive force's sign; the gateway emulation owns the shift delay), no tyre saturation, no load
 * transfer.
 *
 * Conventions: ISO 8855, x forward, y left, yaw counter-clockwise; SI units; the position
 * and speed refer to the centre of gravity. speed_mps, accel_mps2 and the wheel speeds are
 * signed in the vehicle frame (negative while reversing); distance_m is signed too (it
 * integrates the signed speed: backing 10 m takes it down by 10 m).
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"

#define MODEL_GUID "{5f0b7c7e-3d1a-4c55-9a57-b1f0a7e2c001}"

typedef enum { CAUS_PARAMETER, CAUS_INPUT, CAUS_OUTPUT } Causality;

/* One row per model variable: value reference (= position), name, causality, start value.
 * The value references and start values must match modelDescription.xml; the tests compare
 * them through the FMI interface. */
#define VARIABLES(X)                                                       \
    X(MASS_KG, "mass_kg", CAUS_PARAMETER, 1650.0)                          \
    X(YAW_INERTIA_KGM2, "yaw_inertia_kgm2", CAUS_PARAMETER, 2900.0)        \
    X(LF_M, "lf_m", CAUS_PARAMETER, 1.30)                                  \
    X(LR_M, "lr_m", CAUS_PARAMETER, 1.42)                                  \
    X(TRACK_WIDTH_M, "track_width_m", CAUS_PARAMETER, 1.55)                \
    X(CF_NPRAD, "cornering_stiffness_front_nprad", CAUS_PARAMETER, 85000.0) \
    X(CR_NPRAD, "cornering_stiffness_rear_nprad", CAUS_PARAMETER, 95000.0)  \
    X(DRIVE_FORCE_MAX_N, "drive_force_max_n", CAUS_PARAMETER, 5200.0)      \
    X(DRIVE_POWER_MAX_W, "drive_power_max_w", CAUS_PARAMETER, 103000.0)    \
    X(DRIVE_TAU_S, "drive_tau_s", CAUS_PARAMETER, 0.25)                    \
    X(BRAKE_GAIN_NPBAR, "brake_gain_npbar", CAUS_PARAMETER, 140.0)         \
    X(BRAKE_TAU_S, "brake_tau_s", CAUS_PARAMETER, 0.10)                    \
    X(BRAKE_MAX_BAR, "brake_max_bar", CAUS_PARAMETER, 200.0)               \
    X(CDA_M2, "cda_m2", CAUS_PARAMETER, 0.70)                              \
    X(AIR_DENSITY_KGPM3, "air_density_kgpm3", CAUS_PARAMETER, 1.2)         \
    X(C_RR, "c_rr", CAUS_PARAMETER, 0.011)                                 \
    X(GRAVITY_MPS2, "gravity_mps2", CAUS_PARAMETER, 9.81)                  \
    X(STEER_TAU_S, "steer_tau_s", CAUS_PARAMETER, 0.10)                    \
    X(STEER_RATE_MAX_RADPS, "steer_rate_max_radps", CAUS_PARAMETER, 0.7)   \
    X(STEER_MAX_RAD, "steer_max_rad", CAUS_PARAMETER, 0.5235987755982988)  \
    X(V_KINEMATIC_MAX_MPS, "v_kinematic_max_mps", CAUS_PARAMETER, 3.0)     \
    X(V_DYNAMIC_MIN_MPS, "v_dynamic_min_mps", CAUS_PARAMETER, 6.0)         \
    X(STEP_S, "step_s", CAUS_PARAMETER, 0.001)                             \
    X(V0_MPS, "v0_mps", CAUS_PARAMETER, 0.0)                               \
    X(X0_M, "x0_m", CAUS_PARAMETER, 0.0)                                   \
    X(Y0_M, "y0_m", CAUS_PARAMETER, 0.0)                                   \
    X(HEADING0_RAD, "heading0_rad", CAUS_PARAMETER, 0.0)                   \
    X(THROTTLE_PCT, "throttle_pct", CAUS_INPUT, 0.0)                       \
    X(BRAKE_BAR, "brake_bar", CAUS_INPUT, 0.0)                             \
    X(STEER_ANGLE_RAD, "steer_angle_rad", CAUS_INPUT, 0.0)                 \
    X(GRADE_PCT, "grade_pct", CAUS_INPUT, 0.0)                             \
    X(WIND_MPS, "wind_mps", CAUS_INPUT, 0.0)                               \
    X(SPEED_MPS, "speed_mps", CAUS_OUTPUT, 0.0)                            \
    X(ACCEL_MPS2, "accel_mps2", CAUS_OUTPUT, 0.0)                          \
    X(YAW_RATE_RADPS, "yaw_rate_radps", CAUS_OUTPUT, 0.0)                  \
    X(X_M, "x_m", CAUS_OUTPUT, 0.0)                                        \
    X(Y_M, "y_m", CAUS_OUTPUT, 0.0)                                        \
    X(HEADING_RAD, "heading_rad", CAUS_OUTPUT, 0.0)                        \
    X(DISTANCE_M, "distance_m", CAUS_OUTPUT, 0.0)                          \
    X(WHEEL_SPEED_FL_MPS, "wheel_speed_fl_mps", CAUS_OUTPUT, 0.0)          \
    X(WHEEL_SPEED_FR_MPS, "wheel_speed_fr_mps", CAUS_OUTPUT, 0.0)          \
    X(WHEEL_SPEED_RL_MPS, "wheel_speed_rl_mps", CAUS_OUTPUT, 0.0)          \
    X(WHEEL_SPEED_RR_MPS, "wheel_speed_rr_mps", CAUS_OUTPUT, 0.0)          \
    X(BRAKE_BAR_ACTUAL, "brake_bar_actual", CAUS_OUTPUT, 0.0)              \
    X(STEER_ANGLE_RAD_ACTUAL, "steer_angle_rad_actual", CAUS_OUTPUT, 0.0)  \
    X(DRIVE_FORCE_N, "drive_force_n", CAUS_OUTPUT, 0.0)                    \
    X(LATERAL_SPEED_MPS, "lateral_speed_mps", CAUS_OUTPUT, 0.0)            \
    X(GEAR, "gear", CAUS_INPUT, 1.0)

#define AS_ENUM(id, name, caus, start) VR_##id,
enum { VARIABLES(AS_ENUM) N_VR };
#define AS_NAME(id, name, caus, start) name,
static const char* const VAR_NAMES[N_VR] = {VARIABLES(AS_NAME)};
#define AS_CAUS(id, name, caus, start) caus,
static const Causality VAR_CAUSALITY[N_VR] = {VARIABLES(AS_CAUS)};
#define AS_START(id, name, caus, start) start,
static const double VAR_START[N_VR] = {VARIABLES(AS_START)};

typedef enum { MODE_INSTANTIATED, MODE_INIT, MODE_STEP, MODE_TERMINATED } Mode;

/* Everything that evolves in time; an FMU state snapshot is a copy of this struct. */
typedef struct {
    double v[N_VR];     /* variable values, indexed by value reference */
    double vy_dyn_mps;  /* dynamic single-track lateral speed at the CG */
    double r_dyn_radps; /* dynamic single-track yaw rate */
    double time_s;
    int mode;
} ModelState;

typedef struct {
    ModelState s;
    fmi2CallbackFunctions cb;
    char instance_name[128];
    int logging_on;
} Instance;

#define SERIAL_MAGIC "BYWPAS01"
#define SERIAL_MAGIC_LEN 8

static void log_msg(Instance* inst, fmi2Status status, const char* fmt, ...) {
    char buf[512];
    va_list ap;
    if (inst->cb.logger == NULL || (status == fmi2OK && !inst->logging_on)) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    inst->cb.logger(inst->cb.componentEnvironment, inst->instance_name, status,
                    status >= fmi2Error ? "logStatusError" : "logAll", "%s", buf);
}

static double clamp(double x, double lo, double hi) { return x < lo ? lo : (x > hi ? hi : x); }

/* Exact discretisation of a first-order lag over h: y += (u - y) * lag_gain(h, tau). */
static double lag_gain(double h, double tau) { return tau > 0.0 ? 1.0 - exp(-h / tau) : 1.0; }

static double drive_force_command_n(const double* v, double speed_mps) {
    const double throttle = clamp(v[VR_THROTTLE_PCT], 0.0, 100.0);
    /* Below 1 m/s the power limit would demand unbounded force; the force limit rules there. */
    const double limit_n = fmin(v[VR_DRIVE_FORCE_MAX_N], v[VR_DRIVE_POWER_MAX_W] / fmax(fabs(speed_mps), 1.0));
    /* The gear only turns the drive force around (no ratios); 0 is neutral. */
    return clamp(v[VR_GEAR], -1.0, 1.0) * throttle / 100.0 * limit_n;
}

static void kinematic_lateral(const double* v, double speed_mps, double delta_rad, double* vy_mps,
                              double* r_radps) {
    const double l = v[VR_LF_M] + v[VR_LR_M];
    const double tan_delta = tan(delta_rad);
    /* No-slip bicycle referred to the CG: the rear axle moves along the body axis. */
    *vy_mps = speed_mps * v[VR_LR_M] / l * tan_delta;
    *r_radps = speed_mps * tan_delta / l;
}

static double blend_weight(const double* v, double speed_mps) {
    /* 0 = kinematic, 1 = dynamic; reverse (speed < 0) always kinematic. */
    return clamp((speed_mps - v[VR_V_KINEMATIC_MAX_MPS]) / (v[VR_V_DYNAMIC_MIN_MPS] - v[VR_V_KINEMATIC_MAX_MPS]),
                 0.0, 1.0);
}

static void compute_outputs(ModelState* s) {
    double* v = s->v;
    const double speed = v[VR_SPEED_MPS];
    const double delta = v[VR_STEER_ANGLE_RAD_ACTUAL];
    double vy_kin, r_kin;
    kinematic_lateral(v, speed, delta, &vy_kin, &r_kin);
    const double w = blend_weight(v, speed);
    const double vy = w * s->vy_dyn_mps + (1.0 - w) * vy_kin;
    const double r = w * s->r_dyn_radps + (1.0 - w) * r_kin;
    const double half_track = 0.5 * v[VR_TRACK_WIDTH_M];
    const double vy_front = vy + v[VR_LF_M] * r;
    const double c = cos(delta), sn = sin(delta);
    v[VR_YAW_RATE_RADPS] = r;
    v[VR_LATERAL_SPEED_MPS] = vy;
    /* Signed rolling speeds: contact-point velocity projected on each wheel's heading. */
    v[VR_WHEEL_SPEED_RL_MPS] = speed - half_track * r;
    v[VR_WHEEL_SPEED_RR_MPS] = speed + half_track * r;
    v[VR_WHEEL_SPEED_FL_MPS] = (speed - half_track * r) * c + vy_front * sn;
    v[VR_WHEEL_SPEED_FR_MPS] = (speed + half_track * r) * c + vy_front * sn;
}

/* Initial state from the parameters, with the actuators settled at the current inputs so a
 * car started held on a grade (brake input set before initialisation) does not roll first. */
static void init_states(ModelState* s) {
    double* v = s->v;
    const double max_delta = v[VR_STEER_MAX_RAD];
    v[VR_SPEED_MPS] = v[VR_V0_MPS] + 0.0; /* + 0.0 turns -0.0 into +0.0 */
    v[VR_ACCEL_MPS2] = 0.0;
    v[VR_X_M] = v[VR_X0_M];
    v[VR_Y_M] = v[VR_Y0_M];
    v[VR_HEADING_RAD] = v[VR_HEADING0_RAD];
    v[VR_DISTANCE_M] = 0.0;
    v[VR_BRAKE_BAR_ACTUAL] = clamp(v[VR_BRAKE_BAR], 0.0, v[VR_BRAKE_MAX_BAR]);
    v[VR_STEER_ANGLE_RAD_ACTUAL] = clamp(v[VR_STEER_ANGLE_RAD], -max_delta, max_delta);
    v[VR_DRIVE_FORCE_N] = drive_force_command_n(v, v[VR_SPEED_MPS]);
    kinematic_lateral(v, v[VR_SPEED_MPS], v[VR_STEER_ANGLE_RAD_ACTUAL], &s->vy_dyn_mps, &s->r_dyn_radps);
    compute_outputs(s);
}

static void substep(ModelState* s, double h) {
    double* v = s->v;
    const double m = v[VR_MASS_KG];
    const double g = v[VR_GRAVITY_MPS2];
    const double lf = v[VR_LF_M], lr = v[VR_LR_M];
    const double speed = v[VR_SPEED_MPS];

    /* Actuators. Steering: saturate the request, lag it, then limit the rate. */
    const double max_delta = v[VR_STEER_MAX_RAD];
    const double delta_req = clamp(v[VR_STEER_ANGLE_RAD], -max_delta, max_delta);
    const double max_step = v[VR_STEER_RATE_MAX_RADPS] * h;
    const double d_delta =
        clamp((delta_req - v[VR_STEER_ANGLE_RAD_ACTUAL]) * lag_gain(h, v[VR_STEER_TAU_S]), -max_step, max_step);
    const double delta = clamp(v[VR_STEER_ANGLE_RAD_ACTUAL] + d_delta, -max_delta, max_delta);
    v[VR_STEER_ANGLE_RAD_ACTUAL] = delta;

    const double p_cmd = clamp(v[VR_BRAKE_BAR], 0.0, v[VR_BRAKE_MAX_BAR]);
    v[VR_BRAKE_BAR_ACTUAL] += (p_cmd - v[VR_BRAKE_BAR_ACTUAL]) * lag_gain(h, v[VR_BRAKE_TAU_S]);
    v[VR_DRIVE_FORCE_N] += (drive_force_command_n(v, speed) - v[VR_DRIVE_FORCE_N]) * lag_gain(h, v[VR_DRIVE_TAU_S]);

    /* Longitudinal forces. Grade in percent = 100 * rise / run. */
    const double theta = atan(v[VR_GRADE_PCT] / 100.0);
    const double v_air = speed + v[VR_WIND_MPS];
    const double f_aero = -0.5 * v[VR_AIR_DENSITY_KGPM3] * v[VR_CDA_M2] * v_air * fabs(v_air);
    const double f_grade = -m * g * sin(theta);
    const double f_free = v[VR_DRIVE_FORCE_N] + f_aero + f_grade;
    const double f_friction_max =
        v[VR_BRAKE_GAIN_NPBAR] * v[VR_BRAKE_BAR_ACTUAL] + v[VR_C_RR] * m * g * cos(theta);
    double speed_new;
    if (speed == 0.0) {
        if (fabs(f_free) <= f_friction_max) {
            speed_new = 0.0; /* stiction holds the car */
        } else {
            const double f_net = f_free - copysign(f_friction_max, f_free);
            speed_new = f_net / m * h;
        }
    } else {
        const double sign = speed > 0.0 ? 1.0 : -1.0;
        speed_new = speed + (f_free - sign * f_friction_max) / m * h;
        /* Friction cannot reverse the motion within a step: stop exactly at zero and let the
         * stiction branch decide on the next step whether the car rolls the other way. */
        if (speed_new * sign <= 0.0) speed_new = 0.0;
    }
    v[VR_ACCEL_MPS2] = (speed_new - speed) / h;
    v[VR_SPEED_MPS] = speed_new;

    /* Lateral single-track. */
    double vy_kin, r_kin;
    kinematic_lateral(v, speed_new, delta, &vy_kin, &r_kin);
    const double w = blend_weight(v, speed_new);
    if (w <= 0.0) {
        s->vy_dyn_mps = vy_kin;
        s->r_dyn_radps = r_kin;
    } else {
        /* Linear tyres; speed_new >= v_kinematic_max_mps > 0 here, so no division by zero. */
        const double vy = s->vy_dyn_mps, r = s->r_dyn_radps;
        const double alpha_f = delta - (vy + lf * r) / speed_new;
        const double alpha_r = -(vy - lr * r) / speed_new;
        const double fy_f = v[VR_CF_NPRAD] * alpha_f;
        const double fy_r = v[VR_CR_NPRAD] * alpha_r;
        const double cos_delta = cos(delta);
        s->vy_dyn_mps += ((fy_f * cos_delta + fy_r) / m - speed_new * r) * h;
        s->r_dyn_radps += (lf * fy_f * cos_delta - lr * fy_r) / v[VR_YAW_INERTIA_KGM2] * h;
    }
    const double vy = w * s->vy_dyn_mps + (1.0 - w) * vy_kin;
    const double r = w * s->r_dyn_radps + (1.0 - w) * r_kin;

    const double speed_mid = 0.5 * (speed + speed_new);
    const double heading_mid = v[VR_HEADING_RAD] + 0.5 * r * h;
    const double ch = cos(heading_mid), sh = sin(heading_mid);
    v[VR_X_M] += (speed_mid * ch - vy * sh) * h;
    v[VR_Y_M] += (speed_mid * sh + vy * ch) * h;
    v[VR_HEADING_RAD] += r * h;
    v[VR_DISTANCE_M] += speed_mid * h;
}

static int check_parameters(Instance* inst) {
    const double* v = inst->s.v;
    int ok = 1;
    int vr;
    for (vr = 0; vr < N_VR; vr++) {
        if (VAR_CAUSALITY[vr] == CAUS_PARAMETER && !isfinite(v[vr])) {
            log_msg(inst, fmi2Error, "parameter %s = %g is not finite", VAR_NAMES[vr], v[vr]);
            ok = 0;
        }
    }
#define REQUIRE(cond, id, what)                                                                   \
    if (!(cond)) {                                                                                \
        log_msg(inst, fmi2Error, "parameter %s = %g: %s", VAR_NAMES[VR_##id], v[VR_##id], what); \
        ok = 0;                                                                                   \
    }
    REQUIRE(v[VR_MASS_KG] > 0.0, MASS_KG, "must be > 0");
    REQUIRE(v[VR_YAW_INERTIA_KGM2] > 0.0, YAW_INERTIA_KGM2, "must be > 0");
    REQUIRE(v[VR_LF_M] > 0.0, LF_M, "must be > 0");
    REQUIRE(v[VR_LR_M] > 0.0, LR_M, "must be > 0");
    REQUIRE(v[VR_TRACK_WIDTH_M] > 0.0, TRACK_WIDTH_M, "must be > 0");
    REQUIRE(v[VR_CF_NPRAD] > 0.0, CF_NPRAD, "must be > 0");
    REQUIRE(v[VR_CR_NPRAD] > 0.0, CR_NPRAD, "must be > 0");
    REQUIRE(v[VR_DRIVE_FORCE_MAX_N] >= 0.0, DRIVE_FORCE_MAX_N, "must be >= 0");
    REQUIRE(v[VR_DRIVE_POWER_MAX_W] >= 0.0, DRIVE_POWER_MAX_W, "must be >= 0");
    REQUIRE(v[VR_DRIVE_TAU_S] >= 0.0, DRIVE_TAU_S, "must be >= 0");
    REQUIRE(v[VR_BRAKE_GAIN_NPBAR] >= 0.0, BRAKE_GAIN_NPBAR, "must be >= 0");
    REQUIRE(v[VR_BRAKE_TAU_S] >= 0.0, BRAKE_TAU_S, "must be >= 0");
    REQUIRE(v[VR_BRAKE_MAX_BAR] >= 0.0, BRAKE_MAX_BAR, "must be >= 0");
    REQUIRE(v[VR_CDA_M2] >= 0.0, CDA_M2, "must be >= 0");
    REQUIRE(v[VR_AIR_DENSITY_KGPM3] >= 0.0, AIR_DENSITY_KGPM3, "must be >= 0");
    REQUIRE(v[VR_C_RR] >= 0.0, C_RR, "must be >= 0");
    REQUIRE(v[VR_GRAVITY_MPS2] > 0.0, GRAVITY_MPS2, "must be > 0");
    REQUIRE(v[VR_STEER_TAU_S] >= 0.0, STEER_TAU_S, "must be >= 0");
    REQUIRE(v[VR_STEER_RATE_MAX_RADPS] > 0.0, STEER_RATE_MAX_RADPS, "must be > 0");
    REQUIRE(v[VR_STEER_MAX_RAD] > 0.0 && v[VR_STEER_MAX_RAD] < 1.5, STEER_MAX_RAD, "must be in (0, 1.5) rad");
    REQUIRE(v[VR_V_KINEMATIC_MAX_MPS] > 0.0, V_KINEMATIC_MAX_MPS, "must be > 0");
    REQUIRE(v[VR_V_DYNAMIC_MIN_MPS] > v[VR_V_KINEMATIC_MAX_MPS], V_DYNAMIC_MIN_MPS,
            "must be > v_kinematic_max_mps");
    REQUIRE(v[VR_STEP_S] >= 1e-6 && v[VR_STEP_S] <= 0.1, STEP_S, "must be in [1e-6, 0.1] s");
#undef REQUIRE
    return ok;
}

static void set_defaults(ModelState* s) {
    memset(s, 0, sizeof *s);
    memcpy(s->v, VAR_START, sizeof VAR_START);
    s->mode = MODE_INSTANTIATED;
}

/* Every entry point starts here: a NULL component is the caller's error, reported as such. */
#define INSTANCE(c, fname)               \
    Instance* inst = (Instance*)(c);     \
    (void)(fname);                       \
    if (inst == NULL) return fmi2Error;  \
    (void)inst;

static fmi2Status bad_mode(Instance* inst, const char* fname) {
    log_msg(inst, fmi2Error, "%s is not allowed in mode %d", fname, inst->s.mode);
    return fmi2Error;
}

/* ---- FMI 2.0 common functions ---------------------------------------------------------- */

const char* fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char* fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    INSTANCE(c, "fmi2SetDebugLogging");
    (void)nCategories;
    (void)categories;
    inst->logging_on = loggingOn ? 1 : 0;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions* functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Instance* inst;
    (void)fmuResourceLocation;
    (void)visible;
    if (functions == NULL || functions->allocateMemory == NULL || functions->freeMemory == NULL) return NULL;
    inst = (Instance*)functions->allocateMemory(1, sizeof(Instance));
    if (inst == NULL) return NULL;
    inst->cb = *functions;
    snprintf(inst->instance_name, sizeof inst->instance_name, "%s", instanceName ? instanceName : "passat");
    inst->logging_on = loggingOn ? 1 : 0;
    if (fmuType != fmi2CoSimulation) {
        log_msg(inst, fmi2Error, "passat is a Co-Simulation FMU only");
        functions->freeMemory(inst);
        return NULL;
    }
    if (fmuGUID == NULL || strcmp(fmuGUID, MODEL_GUID) != 0) {
        log_msg(inst, fmi2Error, "GUID %s does not match the binary's %s", fmuGUID ? fmuGUID : "(null)",
                MODEL_GUID);
        functions->freeMemory(inst);
        return NULL;
    }
    set_defaults(&inst->s);
    return inst;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance* inst = (Instance*)c;
    if (inst != NULL) inst->cb.freeMemory(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    INSTANCE(c, "fmi2SetupExperiment");
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (inst->s.mode != MODE_INSTANTIATED) return bad_mode(inst, "fmi2SetupExperiment");
    inst->s.time_s = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    INSTANCE(c, "fmi2EnterInitializationMode");
    if (inst->s.mode != MODE_INSTANTIATED) return bad_mode(inst, "fmi2EnterInitializationMode");
    inst->s.mode = MODE_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    INSTANCE(c, "fmi2ExitInitializationMode");
    if (inst->s.mode != MODE_INIT) return bad_mode(inst, "fmi2ExitInitializationMode");
    if (!check_parameters(inst)) return fmi2Error;
    init_states(&inst->s);
    inst->s.mode = MODE_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    INSTANCE(c, "fmi2Terminate");
    inst->s.mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    INSTANCE(c, "fmi2Reset");
    set_defaults(&inst->s);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    size_t i;
    INSTANCE(c, "fmi2GetReal");
    /* Outputs depend on parameters and inputs already during initialisation. */
    if (inst->s.mode == MODE_INIT) init_states(&inst->s);
    for (i = 0; i < nvr; i++) {
        if (vr[i] >= N_VR) {
            log_msg(inst, fmi2Error, "fmi2GetReal: unknown value reference %u", vr[i]);
            return fmi2Error;
        }
        value[i] = inst->s.v[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    size_t i;
    INSTANCE(c, "fmi2SetReal");
    /* Validate everything first so a rejected call changes nothing. */
    for (i = 0; i < nvr; i++) {
        if (vr[i] >= N_VR) {
            log_msg(inst, fmi2Error, "fmi2SetReal: unknown value reference %u", vr[i]);
            return fmi2Error;
        }
        if (VAR_CAUSALITY[vr[i]] == CAUS_OUTPUT) {
            log_msg(inst, fmi2Error, "fmi2SetReal: %s is an output and cannot be set", VAR_NAMES[vr[i]]);
            return fmi2Error;
        }
        if (VAR_CAUSALITY[vr[i]] == CAUS_PARAMETER && inst->s.mode != MODE_INSTANTIATED &&
            inst->s.mode != MODE_INIT) {
            log_msg(inst, fmi2Error, "fmi2SetReal: %s is a fixed parameter; set it before initialisation ends",
                    VAR_NAMES[vr[i]]);
            return fmi2Error;
        }
        if (!isfinite(value[i])) {
            log_msg(inst, fmi2Error, "fmi2SetReal: %s = %g is not finite", VAR_NAMES[vr[i]], value[i]);
            return fmi2Error;
        }
    }
    for (i = 0; i < nvr; i++) inst->s.v[vr[i]] = value[i];
    return fmi2OK;
}

static fmi2Status no_such_variables(fmi2Component c, size_t nvr, const char* fname) {
    INSTANCE(c, fname);
    if (nvr == 0) return fmi2OK;
    log_msg(inst, fmi2Error, "%s: the model has only Real variables", fname);
    return fmi2Error;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, nvr, "fmi2GetInteger");
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, nvr, "fmi2GetBoolean");
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, nvr, "fmi2GetString");
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, nvr, "fmi2SetInteger");
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, nvr, "fmi2SetBoolean");
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    (void)vr;
    (void)value;
    return no_such_variables(c, nvr, "fmi2SetString");
}

/* ---- FMU state: the whole model state is one flat struct ------------------------------- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* FMUstate) {
    ModelState* copy;
    INSTANCE(c, "fmi2GetFMUstate");
    copy = (ModelState*)(*FMUstate);
    if (copy == NULL) {
        copy = (ModelState*)inst->cb.allocateMemory(1, sizeof(ModelState));
        if (copy == NULL) return fmi2Error;
    }
    *copy = inst->s;
    *FMUstate = copy;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    INSTANCE(c, "fmi2SetFMUstate");
    if (FMUstate == NULL) return fmi2Error;
    inst->s = *(const ModelState*)FMUstate;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* FMUstate) {
    INSTANCE(c, "fmi2FreeFMUstate");
    if (FMUstate != NULL && *FMUstate != NULL) {
        inst->cb.freeMemory(*FMUstate);
        *FMUstate = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t* size) {
    INSTANCE(c, "fmi2SerializedFMUstateSize");
    (void)FMUstate;
    *size = SERIAL_MAGIC_LEN + sizeof(ModelState);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    INSTANCE(c, "fmi2SerializeFMUstate");
    if (FMUstate == NULL || size < SERIAL_MAGIC_LEN + sizeof(ModelState)) return fmi2Error;
    memcpy(serializedState, SERIAL_MAGIC, SERIAL_MAGIC_LEN);
    memcpy(serializedState + SERIAL_MAGIC_LEN, FMUstate, sizeof(ModelState));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate* FMUstate) {
    ModelState* copy;
    INSTANCE(c, "fmi2DeSerializeFMUstate");
    if (size != SERIAL_MAGIC_LEN + sizeof(ModelState) || memcmp(serializedState, SERIAL_MAGIC, SERIAL_MAGIC_LEN) != 0) {
        log_msg(inst, fmi2Error, "fmi2DeSerializeFMUstate: not a passat state of this build (%zu bytes)", size);
        return fmi2Error;
    }
    copy = (ModelState*)(*FMUstate);
    if (copy == NULL) {
        copy = (ModelState*)inst->cb.allocateMemory(1, sizeof(ModelState));
        if (copy == NULL) return fmi2Error;
    }
    memcpy(copy, serializedState + SERIAL_MAGIC_LEN, sizeof(ModelState));
    *FMUstate = copy;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    INSTANCE(c, "fmi2GetDirectionalDerivative");
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    log_msg(inst, fmi2Error, "fmi2GetDirectionalDerivative is not provided");
    return fmi2Error;
}

/* ---- Co-Simulation --------------------------------------------------------------------- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    INSTANCE(c, "fmi2SetRealInputDerivatives");
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    log_msg(inst, fmi2Error, "passat does not interpolate inputs");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    INSTANCE(c, "fmi2GetRealOutputDerivatives");
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    log_msg(inst, fmi2Error, "passat does not provide output derivatives");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    double n_steps, h;
    long i, n;
    INSTANCE(c, "fmi2DoStep");
    (void)noSetFMUStatePriorToCurrentPoint;
    if (inst->s.mode != MODE_STEP) return bad_mode(inst, "fmi2DoStep");
    if (!(communicationStepSize >= 0.0) || !isfinite(communicationStepSize)) {
        log_msg(inst, fmi2Error, "fmi2DoStep: step size %g is not a finite value >= 0", communicationStepSize);
        return fmi2Error;
    }
    if (communicationStepSize == 0.0) return fmi2OK;
    /* Equal sub-steps no longer than step_s; the 1e-9 keeps 0.010 / 0.001 from becoming 11. */
    n_steps = ceil(communicationStepSize / inst->s.v[VR_STEP_S] - 1e-9);
    if (n_steps > 1e8) {
        log_msg(inst, fmi2Error, "fmi2DoStep: step size %g needs more than 1e8 sub-steps", communicationStepSize);
        return fmi2Error;
    }
    n = n_steps < 1.0 ? 1 : (long)n_steps;
    h = communicationStepSize / (double)n;
    for (i = 0; i < n; i++) substep(&inst->s, h);
    compute_outputs(&inst->s);
    inst->s.time_s = currentCommunicationPoint + communicationStepSize;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    INSTANCE(c, "fmi2CancelStep");
    log_msg(inst, fmi2Error, "fmi2CancelStep: doStep never runs asynchronously");
    return fmi2Error;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status* value) {
    INSTANCE(c, "fmi2GetStatus");
    if (s != fmi2DoStepStatus) return fmi2Discard;
    *value = fmi2OK;
    return fmi2OK;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real* value) {
    INSTANCE(c, "fmi2GetRealStatus");
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *value = inst->s.time_s;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer* value) {
    INSTANCE(c, "fmi2GetIntegerStatus");
    (void)s;
    (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean* value) {
    INSTANCE(c, "fmi2GetBooleanStatus");
    (void)s;
    if (s == fmi2Terminated) {
        *value = fmi2False;
        return fmi2OK;
    }
    (void)value;
    return fmi2Discard;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String* value) {
    INSTANCE(c, "fmi2GetStringStatus");
    (void)s;
    (void)value;
    return fmi2Discard;
}
