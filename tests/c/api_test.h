/*
 * Shared by the two files of the C ABI test program: api_test.c (the checks, synthetic data,
 * main; calls that must fail or return no result, the noise callback, the estimator alone) and
 * api_registration_test.c (registrations and their results). main runs the tests of both in
 * one order on one context: each sees the settings the earlier ones left.
 */
#ifndef SIE_API_TEST_H
#define SIE_API_TEST_H

#include "sie.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---- checks: counted, and reported with file and line when they fail ---------------------- */

void check(int ok, const char *what, const char *file, int line);
void expect_status(sie_status got, sie_status expected, const char *call, const sie_context *ctx,
                   const char *file, int line);
#define CHECK(cond) check((cond) ? 1 : 0, #cond, __FILE__, __LINE__)
#define EXPECT(ctx, call, expected) expect_status((call), (expected), #call, (ctx), __FILE__, __LINE__)
int error_contains(const sie_context *ctx, const char *needle);

/* ---- deterministic synthetic data (api_test.c) -------------------------------------------- */

extern unsigned long long rng_state;
double uniform(double lo, double hi);
double gaussian(double sigma);
double max_abs_difference(const double *a, const double *b, size_t n);
int all_equal(const double *values, size_t n, double expected);

extern const double IDENTITY[16];
#define SENTINEL (-12345.0)

/* Matched pairs under a known transform; every 5th target is an outlier. */
#define PAIRS 1000
extern float pair_source[PAIRS * 3];
extern float pair_target[PAIRS * 3];
extern double pair_source_d[PAIRS * 3];
extern double pair_target_d[PAIRS * 3];
extern double pair_truth[16];
int is_outlier(size_t i);

/* Three orthogonal 15x15 planes (a room corner) and the source seen from a moved sensor. */
#define PLANE_SIDE 15
#define CLOUD (3 * PLANE_SIDE * PLANE_SIDE)
typedef struct {
    float x, y, z, pad;
} padded_point; /* like pcl::PointXYZ: 16-byte stride */
typedef struct {
    float x, y, z, pad0;
    float normal_x, normal_y, normal_z, pad1;
    float curvature, pad2[3];
} point_normal; /* like pcl::PointNormal: 48-byte stride */
extern padded_point cloud_source[CLOUD];
extern padded_point cloud_target[CLOUD];
extern point_normal cloud_target_normals[CLOUD];
extern double cloud_source_d[CLOUD * 3];
extern double cloud_target_d[CLOUD * 3];
extern double cloud_truth[16];

/* ---- tests called across the two files ---------------------------------------------------- */

/* api_test.c: every getter answers NO_RESULT. */
void test_no_result(sie_context *ctx);
/* api_registration_test.c, run by main. */
void test_correspondence_registration(sie_context *ctx);
void test_cloud_registration(sie_context *ctx);
void test_prepared_target(sie_context *ctx);
void test_odometry(sie_context *ctx);
void test_progress_transform(sie_context *ctx);
void test_verdicts(sie_context *ctx);
void test_cancellation_and_non_finite(sie_context *ctx);

#endif
