/*
 * incise.h: the incise wire records for C.
 *
 * IncisePose and InciseForce have the layout of incise_protocol::raw::RawToolPose and
 * RawToolForce (the records iceoryx2 carries in shared memory), field for field; the static
 * assertions below and the Rust test protocol/tests/c_layout.rs hold both sides to it. Units are
 * SI: metres, seconds, newtons, radians; positions in the scene's frame.
 */
#ifndef INCISE_H
#define INCISE_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* IncisePose.has: which optional fields are given. */
#define INCISE_HAS_LINEAR_VELOCITY 1u
#define INCISE_HAS_ANGULAR_VELOCITY 2u

/* InciseForce.flags (incise.v1.ForceFlag). */
#define INCISE_FORCE_IN_CONTACT 1u
#define INCISE_FORCE_CUTTING 2u
#define INCISE_FORCE_CLAMPED 4u
#define INCISE_FORCE_STALE 8u

/* A tool pose (incise.v1.ToolPose). */
typedef struct IncisePose {
    uint64_t sequence;            /* +1 per pose sent for this tool */
    uint64_t timestamp_ns;        /* the driver's monotonic clock */
    double position[3];           /* the tool's origin (m) */
    double orientation[4];        /* unit quaternion w, x, y, z */
    double linear_velocity[3];    /* m/s, if has & INCISE_HAS_LINEAR_VELOCITY */
    double angular_velocity[3];   /* rad/s, if has & INCISE_HAS_ANGULAR_VELOCITY */
    double gripper_angle;         /* rad, >= 0 */
    uint32_t tool_id;
    uint32_t buttons;             /* one bit per button */
    uint32_t has;
    uint32_t client;              /* the session; incise_send_pose fills in 0 */
} IncisePose;

/* The force answering a pose (incise.v1.ToolForce). */
typedef struct InciseForce {
    uint64_t pose_sequence;       /* the IncisePose.sequence it answers */
    uint64_t timestamp_ns;        /* the server's monotonic clock */
    double force[3];              /* N, scene frame */
    double torque[3];             /* N m, about the tool's origin */
    double gripper_force;         /* N */
    uint32_t tool_id;
    uint32_t flags;               /* INCISE_FORCE_* bits */
} InciseForce;

/*
 * The client library (libincise_c, clients/c): one tool's connection to incise-server.
 *
 * incise_connect: transport "zenoh" or "iceoryx2"; scene as the server names it; the tool's id;
 *   endpoint "tcp/HOST:PORT" for zenoh (may be NULL for iceoryx2). NULL on failure.
 * incise_send_pose: 0 sent, -1 failed.
 * incise_recv_force: waits up to timeout_us; 1 with *out set, 0 none came, -1 failed.
 * incise_last_error: the calling thread's last error message.
 */
typedef struct InciseClient InciseClient;

InciseClient *incise_connect(const char *transport, const char *scene, uint32_t tool,
                             const char *endpoint);
int32_t incise_send_pose(const InciseClient *client, const IncisePose *pose);
int32_t incise_recv_force(const InciseClient *client, InciseForce *out, uint32_t timeout_us);
void incise_disconnect(InciseClient *client);
const char *incise_last_error(void);

#if defined(__STDC_VERSION__) && __STDC_VERSION__ >= 201112L
_Static_assert(sizeof(IncisePose) == 144, "IncisePose is 144 bytes");
_Static_assert(offsetof(IncisePose, position) == 16, "IncisePose.position");
_Static_assert(offsetof(IncisePose, gripper_angle) == 120, "IncisePose.gripper_angle");
_Static_assert(offsetof(IncisePose, client) == 140, "IncisePose.client");
_Static_assert(sizeof(InciseForce) == 80, "InciseForce is 80 bytes");
_Static_assert(offsetof(InciseForce, gripper_force) == 64, "InciseForce.gripper_force");
_Static_assert(offsetof(InciseForce, flags) == 76, "InciseForce.flags");
#endif

#ifdef __cplusplus
}
#endif

#endif /* INCISE_H */
