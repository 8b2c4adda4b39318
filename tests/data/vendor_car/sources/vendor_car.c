/*
 * vendor_car: an FMI 2.0 Co-Simulation FMU written apart from bywire's passat model, in the names
 * and units a vehicle-model vendor would use (km/h, Pa, degrees, a pedal fraction, kW, km), so the
 * tests can run bywire's scenarios on an FMU that is not ours through a plant mapping file.
 *
 * Model: a point mass with a lagged drive force (force and power limited; direction input
 * +1/-1/0), a lagged brake pressure acting as Coulomb friction with stiction together with the
 * rolling resistance, drag with head wind and road gradient; a kinematic single track (side-slip
 * angle at the CG from the rear-axle distance), a lagged and rate-limited steering. Semi-implicit
 * Euler with the fixed internal step h_int. The initial speed is the parameter vx_init (km/h).
 * The numbers describe the same car as bywire's passat, so its ECU calibration fits.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"

#define GUID "{8c2d41e0-7b5f-4f0e-a3d9-5e1c9b7a4f10}"
#define KMH_PER_MPS 3.6
#define DEG_PER_RAD 57.29577951308232

/* id, start; the order is the value reference and must match modelDescription.xml. */
#define VARIABLES(X)                                                                       \
    X(M_VEHICLE, 1650.0) X(F_DRIVE_MAX, 5200.0) X(P_DRIVE_MAX, 103.0) X(T_DRIVE, 0.25)      \
    X(K_BRAKE, 0.0014) X(T_BRAKE, 0.10) X(P_BRAKE_MAX, 2.0e7) X(CWA, 0.70) X(RHO_AIR, 1.2)  \
    X(F_ROLL, 0.011) X(WHEELBASE, 2.72) X(L_REAR, 1.42) X(DELTA_MAX, 30.0)                  \
    X(DELTA_RATE_MAX, 40.0) X(T_STEER, 0.10) X(H_INT, 0.0005) X(VX_INIT, 0.0)               \
    X(PEDAL, 0.0) X(P_BRAKE, 0.0) X(DELTA_REQ, 0.0) X(GRADIENT, 0.0) X(HEADWIND, 0.0)        \
    X(DIRECTION, 1.0)                                                                       \
    X(VX, 0.0) X(AX, 0.0) X(YAW_RATE, 0.0) X(POS_X, 0.0) X(POS_Y, 0.0) X(PSI, 0.0) X(ODOMETER, 0.0)

#define AS_ENUM(id, start) id,
enum { VARIABLES(AS_ENUM) N_VARS };
#define AS_START(id, start) start,
static const double START[N_VARS] = {VARIABLES(AS_START)};
#define FIRST_INPUT PEDAL
#define FIRST_OUTPUT VX

typedef struct {
    double p[N_VARS];
    double v_mps, psi_rad, force_drive_n, p_brake_pa, delta_rad; /* states in SI */
    int initialised;
    fmi2CallbackFunctions cb;
    char name[64];
} Car;

static double clamp(double x, double lo, double hi) { return x < lo ? lo : (x > hi ? hi : x); }
static double lag(double h, double tau) { return tau > 0.0 ? 1.0 - exp(-h / tau) : 1.0; }

static void error(Car* car, const char* fmt, ...) {
    char buf[256];
    va_list ap;
    if (car->cb.logger == NULL) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    car->cb.logger(car->cb.componentEnvironment, car->name, fmi2Error, "logStatusError", "%s", buf);
}

static double drive_command_n(const double* p, double v_mps) {
    const double limit = fmin(p[F_DRIVE_MAX], p[P_DRIVE_MAX] * 1000.0 / fmax(fabs(v_mps), 1.0));
    return clamp(p[DIRECTION], -1.0, 1.0) * clamp(p[PEDAL], 0.0, 1.0) * limit;
}

/* Kinematic single track: side-slip angle at the CG and yaw rate. */
static void track(const double* p, double v_mps, double delta_rad, double* beta, double* r) {
    *beta = atan(p[L_REAR] / p[WHEELBASE] * tan(delta_rad));
    *r = v_mps * cos(*beta) * tan(delta_rad) / p[WHEELBASE];
}

static void publish(Car* car, double ax) {
    double beta, r;
    track(car->p, car->v_mps, car->delta_rad, &beta, &r);
    car->p[VX] = car->v_mps * KMH_PER_MPS;
    car->p[AX] = ax;
    car->p[YAW_RATE] = r * DEG_PER_RAD;
    car->p[PSI] = car->psi_rad * DEG_PER_RAD;
}

static void initialise(Car* car) {
    double* p = car->p;
    const double dmax = p[DELTA_MAX] / DEG_PER_RAD;
    car->v_mps = p[VX_INIT] / KMH_PER_MPS;
    car->psi_rad = 0.0;
    car->p_brake_pa = clamp(p[P_BRAKE], 0.0, p[P_BRAKE_MAX]);
    car->delta_rad = clamp(p[DELTA_REQ] / DEG_PER_RAD, -dmax, dmax);
    car->force_drive_n = drive_command_n(p, car->v_mps);
    p[POS_X] = p[POS_Y] = p[ODOMETER] = 0.0;
    publish(car, 0.0);
}

static double integrate(Car* car, double h) {
    double* p = car->p;
    const double m = p[M_VEHICLE], g = 9.81, v = car->v_mps;
    const double dmax = p[DELTA_MAX] / DEG_PER_RAD, rate = p[DELTA_RATE_MAX] / DEG_PER_RAD * h;
    const double d_req = clamp(p[DELTA_REQ] / DEG_PER_RAD, -dmax, dmax);
    double v_new, beta, r;
    car->delta_rad += clamp((d_req - car->delta_rad) * lag(h, p[T_STEER]), -rate, rate);
    car->p_brake_pa += (clamp(p[P_BRAKE], 0.0, p[P_BRAKE_MAX]) - car->p_brake_pa) * lag(h, p[T_BRAKE]);
    car->force_drive_n += (drive_command_n(p, v) - car->force_drive_n) * lag(h, p[T_DRIVE]);
    {
        const double slope = atan(p[GRADIENT]);
        const double v_air = v + p[HEADWIND] / KMH_PER_MPS;
        const double f_free = car->force_drive_n - 0.5 * p[RHO_AIR] * p[CWA] * v_air * fabs(v_air) -
                              m * g * sin(slope);
        const double f_friction = p[K_BRAKE] * car->p_brake_pa + p[F_ROLL] * m * g * cos(slope);
        if (v == 0.0) {
            v_new = fabs(f_free) <= f_friction ? 0.0 : (f_free - copysign(f_friction, f_free)) / m * h;
        } else {
            v_new = v + (f_free - copysign(f_friction, v)) / m * h;
            if (v_new * v <= 0.0) v_new = 0.0; /* friction stops the car, never turns it round */
        }
    }
    car->v_mps = v_new;
    track(p, v_new, car->delta_rad, &beta, &r);
    car->psi_rad += r * h;
    p[POS_X] += v_new * cos(car->psi_rad + beta) * h;
    p[POS_Y] += v_new * sin(car->psi_rad + beta) * h;
    p[ODOMETER] += v_new * h / 1000.0;
    return (v_new - v) / h;
}

/* ---- FMI 2.0 ------------------------------------------------------------------------------ */

const char* fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char* fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String resourceLocation, const fmi2CallbackFunctions* functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Car* car;
    (void)resourceLocation;
    (void)visible;
    (void)loggingOn;
    if (functions == NULL || functions->allocateMemory == NULL || fmuType != fmi2CoSimulation) return NULL;
    if (fmuGUID == NULL || strcmp(fmuGUID, GUID) != 0) return NULL;
    car = (Car*)functions->allocateMemory(1, sizeof(Car));
    if (car == NULL) return NULL;
    car->cb = *functions;
    snprintf(car->name, sizeof car->name, "%s", instanceName ? instanceName : "vendor_car");
    memcpy(car->p, START, sizeof START);
    return car;
}

void fmi2FreeInstance(fmi2Component c) {
    Car* car = (Car*)c;
    if (car != NULL) car->cb.freeMemory(car);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    (void)c;
    (void)on;
    (void)n;
    (void)cats;
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stopDefined, fmi2Real stop) {
    (void)c;
    (void)tolDefined;
    (void)tol;
    (void)start;
    (void)stopDefined;
    (void)stop;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return c ? fmi2OK : fmi2Error; }

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Car* car = (Car*)c;
    if (car == NULL) return fmi2Error;
    if (!(car->p[M_VEHICLE] > 0.0 && car->p[WHEELBASE] > 0.0 && car->p[H_INT] > 0.0)) {
        error(car, "m_vehicle, wheelbase and h_int must be > 0");
        return fmi2Error;
    }
    initialise(car);
    car->initialised = 1;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) { return c ? fmi2OK : fmi2Error; }

fmi2Status fmi2Reset(fmi2Component c) {
    Car* car = (Car*)c;
    if (car == NULL) return fmi2Error;
    memcpy(car->p, START, sizeof START);
    car->initialised = 0;
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    Car* car = (Car*)c;
    size_t i;
    if (car == NULL) return fmi2Error;
    if (!car->initialised) initialise(car);
    for (i = 0; i < nvr; i++) {
        if (vr[i] >= N_VARS) return fmi2Error;
        value[i] = car->p[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    Car* car = (Car*)c;
    size_t i;
    if (car == NULL) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (vr[i] >= FIRST_OUTPUT || (vr[i] < FIRST_INPUT && car->initialised) || !isfinite(value[i])) {
            error(car, "fmi2SetReal: value reference %u cannot take %g now", vr[i], value[i]);
            return fmi2Error;
        }
    }
    for (i = 0; i < nvr; i++) car->p[vr[i]] = value[i];
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Car* car = (Car*)c;
    long i, n;
    double ax = 0.0;
    (void)t;
    (void)noSetPrior;
    if (car == NULL || !car->initialised || !(h >= 0.0) || !isfinite(h)) return fmi2Error;
    if (h == 0.0) return fmi2OK;
    n = (long)ceil(h / car->p[H_INT] - 1e-9);
    if (n < 1) n = 1;
    for (i = 0; i < n; i++) ax = integrate(car, h / (double)n);
    publish(car, ax);
    return fmi2OK;
}

/* ---- what this FMU does not offer ---------------------------------------------------------- */

#define UNSUPPORTED(...) \
    { return fmi2Error; }

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[])
    UNSUPPORTED(c, vr, n, v)
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[])
    UNSUPPORTED(c, vr, n, v)
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[])
    UNSUPPORTED(c, vr, n, v)
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[])
    UNSUPPORTED(c, vr, n, v)
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[])
    UNSUPPORTED(c, vr, n, v)
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[])
    UNSUPPORTED(c, vr, n, v)
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* s) UNSUPPORTED(c, s)
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) UNSUPPORTED(c, s)
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* s) UNSUPPORTED(c, s)
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t* n) UNSUPPORTED(c, s, n)
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n)
    UNSUPPORTED(c, s, b, n)
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate* s)
    UNSUPPORTED(c, b, n, s)
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference k[], size_t nk, const fmi2Real dk[],
                                        fmi2Real du[]) UNSUPPORTED(c, u, nu, k, nk, dk, du)
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real v[])
    UNSUPPORTED(c, vr, n, order, v)
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real v[])
    UNSUPPORTED(c, vr, n, order, v)
fmi2Status fmi2CancelStep(fmi2Component c) UNSUPPORTED(c)
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status* v) UNSUPPORTED(c, k, v)
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real* v) UNSUPPORTED(c, k, v)
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer* v)
    UNSUPPORTED(c, k, v)
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean* v)
    UNSUPPORTED(c, k, v)
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String* v)
    UNSUPPORTED(c, k, v)
