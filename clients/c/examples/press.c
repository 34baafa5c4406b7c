/*
 * press.c: an incise device driver in C, what an OpenHaptics or Force Dimension servo loop
 * looks like against incise-server. It connects one tool, lowers it onto the organ 1 mm per
 * 40 poses at 1 kHz, and prints the force that answers its pose once the tissue pushes back
 * with more than 1 mN.
 *
 *   cc press.c -I protocol/include -L target/release -lincise_c -o press
 *   ./press iceoryx2 demo_organ 0 tcp/127.0.0.1:7447 X Y Z
 *
 * Exit status 0 when a force came back non-zero (in contact), 1 otherwise.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "incise.h"

/* The layout the library and the server use (also asserted in incise.h). */
_Static_assert(sizeof(IncisePose) == 144, "IncisePose");
_Static_assert(sizeof(InciseForce) == 80, "InciseForce");

static uint64_t now_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint64_t)t.tv_sec * 1000000000u + (uint64_t)t.tv_nsec;
}

/* Sleeps until `deadline_ns` on the monotonic clock: a servo loop's fixed period, which also
 * keeps the tool from outrunning the physics (the descent is 1 mm per 40 ms of wall time). */
static void sleep_until(uint64_t deadline_ns) {
    uint64_t now = now_ns();
    if (now >= deadline_ns) return;
    uint64_t wait = deadline_ns - now;
    struct timespec t = {(time_t)(wait / 1000000000u), (long)(wait % 1000000000u)};
    nanosleep(&t, NULL);
}

int main(int argc, char **argv) {
    if (argc != 8) {
        fprintf(stderr, "usage: %s TRANSPORT SCENE TOOL ENDPOINT X Y Z\n", argv[0]);
        return 2;
    }
    uint32_t tool = (uint32_t)atoi(argv[3]);
    InciseClient *client = incise_connect(argv[1], argv[2], tool, argv[4]);
    if (!client) {
        fprintf(stderr, "cannot connect: %s\n", incise_last_error());
        return 2;
    }
    double x = atof(argv[5]), y = atof(argv[6]), z = atof(argv[7]);
    int status = 1;
    uint64_t answered = 0;
    uint64_t start = now_ns();
    for (uint64_t seq = 1; seq <= 40000 && status != 0; ++seq) {
        sleep_until(start + seq * 1000000u); /* 1 kHz */
        IncisePose pose;
        memset(&pose, 0, sizeof pose);
        pose.sequence = seq;
        pose.timestamp_ns = now_ns();
        pose.tool_id = tool;
        pose.position[0] = x;
        pose.position[1] = y;
        pose.position[2] = z + 0.01 - 0.001 * (double)(seq / 40); /* from 1 cm above, 1 mm per 40 */
        pose.orientation[0] = 1.0;
        if (incise_send_pose(client, &pose) != 0) {
            fprintf(stderr, "send: %s\n", incise_last_error());
            break;
        }
        InciseForce f;
        while (incise_recv_force(client, &f, 1000) == 1) {
            if (f.pose_sequence != seq) continue;
            ++answered;
            if (f.force[2] > 1e-3 && (f.flags & INCISE_FORCE_IN_CONTACT)) {
                printf("pose %llu at z %.4f m: force (%.4f, %.4f, %.4f) N, flags %u\n",
                       (unsigned long long)seq, pose.position[2], f.force[0], f.force[1],
                       f.force[2], f.flags);
                status = 0;
            }
            break;
        }
    }
    printf("%llu poses answered\n", (unsigned long long)answered);
    incise_disconnect(client);
    return status;
}
