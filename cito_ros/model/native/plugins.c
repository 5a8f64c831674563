// MuJoCo engine plugins for the state-dependent forces of eq. (2),
//   tau = u + C^(q, qdot) - J_c^T lambda_c,
// evaluated inside MuJoCo's actuation stage so that mj_step, mujoco.rollout
// (any number of threads) and mjd_transitionFD all see the same dynamics.
//
// Both plugins are actuator plugins and keep no data of their own: every
// quantity is read from the mjModel/mjData they are called with, so several
// models (and several simulations of one model) coexist in one process.
//
//   cito.compensated_motor  torque motor on a joint: force = clamp(ctrl) + qfrc_bias[dof] / gear
//                           (gravity, Coriolis and centrifugal compensation, C^ = C).
//   cito.virtual_contact    virtual normal force of the smooth contact models,
//                           gamma = k exp(-(c / k) phi), k = clamp(ctrl), gamma = 0 for k <= 0.
//                           Its transmission is a site (robot candidate) with a refsite (object
//                           candidate, x axis = outward face normal) and gear (1 0 0 0 0 0):
//                           MuJoCo then applies -gamma n at the object candidate and +gamma n at
//                           the robot candidate, i.e. the object is pushed along the inward normal
//                           and the robot feels the reaction.
//
#include "cito_native.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <mujoco/mujoco.h>

static const char* kCurvature = "curvature";

//---------------------------------- shared helpers ----------------------------------------------

static mjtNum clamp_ctrl(const mjModel* m, const mjData* d, int actuator) {
  mjtNum ctrl = d->ctrl[actuator];
  if (m->actuator_ctrllimited[actuator] && !mjDISABLED(mjDSBL_CLAMPCTRL)) {
    const mjtNum* range = m->actuator_ctrlrange + 2 * actuator;
    ctrl = mju_clip(ctrl, range[0], range[1]);
  }
  return ctrl;
}

static int nop_nstate(const mjModel* m, int instance) {
  (void)m; (void)instance;
  return 0;
}

static void nop_reset(const mjModel* m, mjtNum* plugin_state, void* plugin_data, int instance) {
  (void)m; (void)plugin_state; (void)plugin_data; (void)instance;
}

//---------------------------------- cito.compensated_motor --------------------------------------

static int motor_init(const mjModel* m, mjData* d, int instance) {
  for (int i = 0; i < m->nu; i++) {
    if (m->actuator_plugin[i] != instance) continue;
    int joint = m->actuator_trnid[2 * i];
    if (m->actuator_trntype[i] != mjTRN_JOINT ||
        (m->jnt_type[joint] != mjJNT_HINGE && m->jnt_type[joint] != mjJNT_SLIDE)) {
      mju_warning("cito.compensated_motor: actuator %d must drive a hinge or slide joint", i);
      return -1;
    }
    if (m->actuator_gear[6 * i] == 0) {
      mju_warning("cito.compensated_motor: actuator %d has zero gear", i);
      return -1;
    }
  }
  d->plugin_data[instance] = 0;
  return 0;
}

static void motor_compute(const mjModel* m, mjData* d, int instance, int capability_bit) {
  (void)capability_bit;
  for (int i = 0; i < m->nu; i++) {
    if (m->actuator_plugin[i] != instance) continue;
    int dof = m->jnt_dofadr[m->actuator_trnid[2 * i]];
    // qfrc_bias is already computed for this state by mj_fwdVelocity.
    d->actuator_force[i] = clamp_ctrl(m, d, i) + d->qfrc_bias[dof] / m->actuator_gear[6 * i];
  }
}

//---------------------------------- cito.virtual_contact ----------------------------------------

// Curvature c (N/m) from the instance's config; NaN if missing or not a positive number.
static mjtNum curvature(const mjModel* m, int instance) {
  const char* text = mj_getPluginConfig(m, instance, kCurvature);
  if (!text || !text[0]) return NAN;
  char* end = NULL;
  double value = strtod(text, &end);
  if (end == text || *end != '\0' || !(value > 0) || !isfinite(value)) return NAN;
  return value;
}

// Signed distance (m) between the robot candidate (site) and the object candidate (refsite):
// Euclidean distance between the two points, negative when the robot candidate lies inside the
// first box geom of the object candidate's body (penetration).
static mjtNum signed_distance(const mjModel* m, const mjData* d, int site, int refsite) {
  const mjtNum* robot = d->site_xpos + 3 * site;
  const mjtNum* object = d->site_xpos + 3 * refsite;
  mjtNum distance = mju_dist3(robot, object);

  int body = m->site_bodyid[refsite];
  int first = m->body_geomadr[body];
  for (int g = first; first >= 0 && g < first + m->body_geomnum[body]; g++) {
    if (m->geom_type[g] != mjGEOM_BOX) continue;
    mjtNum offset[3], local[3];
    mju_sub3(offset, robot, d->geom_xpos + 3 * g);
    mju_mulMatTVec3(local, d->geom_xmat + 9 * g, offset);
    const mjtNum* half = m->geom_size + 3 * g;
    if (mju_abs(local[0]) < half[0] && mju_abs(local[1]) < half[1] && mju_abs(local[2]) < half[2]) {
      distance = -distance;
    }
    break;
  }
  return distance;
}

static int contact_init(const mjModel* m, mjData* d, int instance) {
  if (mju_isBad(curvature(m, instance))) {
    mju_warning("cito.virtual_contact: config '%s' must be a positive number", kCurvature);
    return -1;
  }
  for (int i = 0; i < m->nu; i++) {
    if (m->actuator_plugin[i] != instance) continue;
    if (m->actuator_trntype[i] != mjTRN_SITE || m->actuator_trnid[2 * i + 1] < 0) {
      mju_warning("cito.virtual_contact: actuator %d needs a site transmission with a refsite", i);
      return -1;
    }
  }
  d->plugin_data[instance] = 0;
  return 0;
}

static void contact_compute(const mjModel* m, mjData* d, int instance, int capability_bit) {
  (void)capability_bit;
  mjtNum c = curvature(m, instance);
  for (int i = 0; i < m->nu; i++) {
    if (m->actuator_plugin[i] != instance) continue;
    mjtNum stiffness = clamp_ctrl(m, d, i);
    mjtNum gamma = 0;
    if (stiffness > 0) {
      mjtNum phi = signed_distance(m, d, m->actuator_trnid[2 * i], m->actuator_trnid[2 * i + 1]);
      gamma = stiffness * mju_exp(-(c / stiffness) * phi);
    }
    d->actuator_force[i] = gamma;
  }
}

//---------------------------------- registration ------------------------------------------------

static void register_actuator_plugin(const char* name, int nattribute, const char** attributes,
                                    int (*init)(const mjModel*, mjData*, int),
                                    void (*compute)(const mjModel*, mjData*, int, int)) {
  mjpPlugin plugin;
  mjp_defaultPlugin(&plugin);
  plugin.name = name;
  plugin.capabilityflags = mjPLUGIN_ACTUATOR;
  plugin.nattribute = nattribute;
  plugin.attributes = attributes;
  plugin.nstate = nop_nstate;
  plugin.init = init;
  plugin.reset = nop_reset;
  plugin.compute = compute;
  mjp_registerPlugin(&plugin);
}

void cito_register_plugins(void) {
  static const char* contact_attributes[] = {"curvature"};
  register_actuator_plugin("cito.compensated_motor", 0, NULL, motor_init, motor_compute);
  register_actuator_plugin("cito.virtual_contact", 1, contact_attributes, contact_init, contact_compute);
}
