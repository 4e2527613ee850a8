/*
 * The C ABI test program's registrations (see api_test.h): correspondences and clouds in float
 * and double with every getter on the result, prepared targets, the progress callback, the
 * quality verdict, cancellation and non-finite points.
 */
#include "api_test.h"

static int finite_non_negative(double value) { return isfinite(value) && value >= 0.0; }

/* The verdict and its evidence: valid codes, finite values (never inf or NaN), and the
 * relations the header documents between them. */
static void check_quality(const sie_summary *s, int correspondences, const char *label) {
    printf("%s: verdict %u, start %u, significance %.1f, conditioning %.3g, sigma/spacing %.3g, margin %.3g, "
           "%u starts (%u agreeing), %u hypotheses, runner-up %.1f\n",
           label, s->verdict, s->start, s->significance, s->conditioning, s->sigma_to_spacing, s->margin,
           s->starts_run, s->agreeing_starts, s->hypotheses, s->runner_up_significance);
    CHECK(s->verdict == SIE_VERDICT_GOOD || s->verdict == SIE_VERDICT_DOUBTFUL ||
          s->verdict == SIE_VERDICT_UNSUPPORTED);
    CHECK(s->start <= SIE_START_KIND_HYPOTHESIS || s->start == SIE_START_KIND_HALF_TURN ||
          s->start == SIE_START_KIND_PERIOD_SHIFT || s->start == SIE_START_KIND_FEATURE_MATCH ||
          s->start == SIE_START_KIND_QUARTER_TURN);
    CHECK(finite_non_negative(s->significance) && finite_non_negative(s->conditioning) &&
          finite_non_negative(s->sigma_to_spacing) && finite_non_negative(s->margin) &&
          finite_non_negative(s->runner_up_significance));
    CHECK(s->conditioning <= 1.0);
    CHECK(s->starts_run >= 1 && s->agreeing_starts >= 1 && s->agreeing_starts <= s->starts_run);
    /* 0 encodes "no start ended elsewhere"; otherwise the ratio of the significances. */
    if (s->runner_up_significance == 0.0) {
        CHECK(s->margin == 0.0);
    } else {
        CHECK(fabs(s->margin - s->significance / s->runner_up_significance) <= 1e-12 * s->margin);
    }
    /* Nothing to judge against chance means no support. */
    CHECK((s->significance > 0.0) == (s->verdict != SIE_VERDICT_UNSUPPORTED));
    if (s->verdict == SIE_VERDICT_GOOD) {
        CHECK(s->conditioning >= 1e-3 && s->sigma_to_spacing <= 1.0);
        CHECK(s->margin == 0.0 || s->margin >= 2.0);
    }
    if (correspondences) {
        CHECK(s->sigma_to_spacing == 0.0);
        CHECK(s->start == SIE_START_KIND_INITIAL_GUESS || s->start == SIE_START_KIND_HYPOTHESIS);
    } else {
        CHECK(s->start != SIE_START_KIND_HYPOTHESIS && s->hypotheses == 0);
    }
}

/* The pose's covariance and information (row-major 6x6, rotation first): symmetric, positive
 * variances, inverse to each other on these well-constrained scenes; either may be read alone,
 * not neither, and two overlapping buffers are refused. */
static void check_pose_uncertainty(sie_context *ctx, const char *label) {
    double covariance[36], information[36], alone[36], shared[40];
    double asymmetry = 0.0, scale = 0.0, off_identity = 0.0;
    size_t r, c, k;
    EXPECT(ctx, sie_context_get_pose_uncertainty(ctx, covariance, information), SIE_STATUS_OK);
    for (r = 0; r < 6; r++) {
        CHECK(covariance[6 * r + r] > 0.0 && information[6 * r + r] > 0.0);
        for (c = 0; c < 6; c++) {
            double product = 0.0;
            CHECK(isfinite(covariance[6 * r + c]) && isfinite(information[6 * r + c]));
            scale = fmax(scale, fabs(covariance[6 * r + c]));
            asymmetry = fmax(asymmetry, fabs(covariance[6 * r + c] - covariance[6 * c + r]));
            for (k = 0; k < 6; k++) {
                product += covariance[6 * r + k] * information[6 * k + c];
            }
            off_identity = fmax(off_identity, fabs(product - (r == c ? 1.0 : 0.0)));
        }
    }
    printf("%s: pose standard deviations %.2e %.2e %.2e rad, %.2e %.2e %.2e; |cov * info - I| %.1e\n", label,
           sqrt(covariance[0]), sqrt(covariance[7]), sqrt(covariance[14]), sqrt(covariance[21]), sqrt(covariance[28]),
           sqrt(covariance[35]), off_identity);
    CHECK(asymmetry <= 1e-12 * scale);
    CHECK(off_identity < 1e-6);
    /* Hundreds of points with mm noise fix the pose to well under 1e-2 (rad or m). */
    CHECK(covariance[0] < 1e-4 && covariance[35] < 1e-4 && information[0] > 1e4);
    for (k = 0; k < 36; k++) {
        alone[k] = SENTINEL;
    }
    EXPECT(ctx, sie_context_get_pose_uncertainty(ctx, NULL, alone), SIE_STATUS_OK);
    CHECK(memcmp(alone, information, sizeof alone) == 0);
    EXPECT(ctx, sie_context_get_pose_uncertainty(ctx, NULL, NULL), SIE_STATUS_NULL_ARGUMENT);
    CHECK(error_contains(ctx, "out_covariance and out_information"));
    for (k = 0; k < 40; k++) {
        shared[k] = SENTINEL;
    }
    EXPECT(ctx, sie_context_get_pose_uncertainty(ctx, shared, shared + 4), SIE_STATUS_INVALID_ARGUMENT);
    CHECK(error_contains(ctx, "overlap"));
    CHECK(all_equal(shared, 40, SENTINEL));
}

/* The registration result must match `truth`; checks every getter on it. */
static void check_pair_result(sie_context *ctx, const double T[16], const char *label) {
    sie_summary summary;
    sie_model model;
    sie_trace_entry *trace;
    double probabilities[PAIRS];
    double small[10];
    int64_t correspondences[PAIRS];
    size_t len = 0, i, bins;
    double inlier_mean = 0.0, outlier_mean = 0.0;
    int identity_matches = 1;
    double error = max_abs_difference(T, pair_truth, 16);

    CHECK(error < 0.01);
    EXPECT(ctx, sie_context_get_summary(ctx, &summary), SIE_STATUS_OK);
    printf("%s: transform error %.2e, sigma %.2e, inlier fraction %.3f, %u iterations, stop reason %u\n", label,
           error, summary.sigma[0], summary.inlier_fraction, summary.iterations, summary.stop_reason);
    CHECK(summary.source_count == PAIRS);
    CHECK(summary.correspondence_count == PAIRS);
    CHECK(summary.iterations >= 1);
    CHECK(summary.stop_reason == SIE_STOP_REASON_CONVERGED || summary.stop_reason == SIE_STOP_REASON_ITERATION_LIMIT);
    CHECK(summary.converged == (summary.stop_reason == SIE_STOP_REASON_CONVERGED));
    CHECK(summary.histogram_count == 1); /* pooled point-to-point */
    /* The inlier noise is N(0, 0.005) per component; constant noise model: input units. */
    CHECK(summary.sigma[0] > 0.0025 && summary.sigma[0] < 0.01);
    CHECK(summary.sigma[1] == 0.0 && summary.beta[2] == 0.0);
    CHECK(summary.inlier_fraction > 0.6 && summary.inlier_fraction < 0.9);
    CHECK(summary.rmse > 0.0 && summary.rmse < 0.05);
    /* 800 inliers at 5 mm among 200 uniform outliers: clearly supported, found by the
     * hypothesis search of the automatic starts (the default). */
    check_quality(&summary, 1, label);
    CHECK(summary.verdict == SIE_VERDICT_GOOD);
    CHECK(summary.significance > 100.0);
    CHECK(summary.hypotheses > 0);

    /* Size query, too-small buffer (untouched), then the real copy. */
    EXPECT(ctx, sie_context_get_inlier_probabilities(ctx, NULL, 0, &len), SIE_STATUS_OK);
    CHECK(len == PAIRS);
    for (i = 0; i < 10; i++) {
        small[i] = SENTINEL;
    }
    len = 777;
    EXPECT(ctx, sie_context_get_inlier_probabilities(ctx, small, 10, &len), SIE_STATUS_BUFFER_TOO_SMALL);
    CHECK(all_equal(small, 10, SENTINEL));
    CHECK(len == 777);
    {
        char expected_count[32];
        sprintf(expected_count, "%d", PAIRS);
        CHECK(error_contains(ctx, expected_count));
    }
    EXPECT(ctx, sie_context_get_inlier_probabilities(ctx, NULL, 5, &len), SIE_STATUS_NULL_ARGUMENT);
    EXPECT(ctx, sie_context_get_inlier_probabilities(ctx, probabilities, PAIRS, NULL), SIE_STATUS_OK);
    for (i = 0; i < PAIRS; i++) {
        if (is_outlier(i)) {
            outlier_mean += probabilities[i] / (PAIRS / 5);
        } else {
            inlier_mean += probabilities[i] / (PAIRS - PAIRS / 5);
        }
    }
    printf("%s: mean P(inlier) %.3f for inliers, %.3f for outliers\n", label, inlier_mean, outlier_mean);
    CHECK(inlier_mean > 0.8);
    CHECK(outlier_mean < 0.2);

    EXPECT(ctx, sie_context_get_correspondences(ctx, correspondences, 3, &len), SIE_STATUS_BUFFER_TOO_SMALL);
    EXPECT(ctx, sie_context_get_correspondences(ctx, correspondences, PAIRS, &len), SIE_STATUS_OK);
    CHECK(len == PAIRS);
    for (i = 0; i < PAIRS; i++) {
        identity_matches &= correspondences[i] == (int64_t)i;
    }
    CHECK(identity_matches);
    check_pose_uncertainty(ctx, label);

    /* Histogram 0: learn the bin count, then fetch every array. */
    EXPECT(ctx, sie_context_get_histogram(ctx, 0, &model, NULL, NULL, NULL, NULL, 0), SIE_STATUS_OK);
    bins = (size_t)model.bins;
    CHECK(bins >= 3);
    CHECK(model.sigma > 0.0 && model.range_hi > model.range_lo && model.peak_found);
    EXPECT(ctx, sie_context_get_histogram(ctx, 1, &model, NULL, NULL, NULL, NULL, 0), SIE_STATUS_INVALID_ARGUMENT);
    EXPECT(ctx, sie_context_get_histogram(ctx, 0, NULL, NULL, NULL, NULL, NULL, 0), SIE_STATUS_NULL_ARGUMENT);
    if (bins >= 3 && bins < 1000000) {
        double *arrays = (double *)malloc(4 * bins * sizeof(double));
        double total = 0.0;
        if (arrays == NULL) {
            abort();
        }
        for (i = 0; i < 4 * bins; i++) {
            arrays[i] = SENTINEL;
        }
        EXPECT(ctx, sie_context_get_histogram(ctx, 0, &model, arrays, NULL, NULL, NULL, bins - 1),
               SIE_STATUS_BUFFER_TOO_SMALL);
        CHECK(all_equal(arrays, bins, SENTINEL));
        EXPECT(ctx,
               sie_context_get_histogram(ctx, 0, &model, arrays, arrays + bins, arrays + 2 * bins, arrays + 3 * bins,
                                         bins),
               SIE_STATUS_OK);
        for (i = 0; i < bins; i++) {
            total += arrays[i];
            CHECK(arrays[3 * bins + i] >= 0.0 && arrays[3 * bins + i] <= 1.0);
            CHECK(arrays[2 * bins + i] >= 0.0 && arrays[2 * bins + i] <= model.alpha * (1.0 + 1e-9));
        }
        CHECK(total >= 1.0 && total <= (double)PAIRS * 3.0); /* pooled: |r| of 3 components per pair */
        free(arrays);
    }

    /* Trace was enabled in test_setters. */
    EXPECT(ctx, sie_context_get_trace(ctx, NULL, 0, &len), SIE_STATUS_OK);
    CHECK(len >= 1);
    trace = (sie_trace_entry *)calloc(len + 1, sizeof(sie_trace_entry));
    if (len >= 1) {
        EXPECT(ctx, sie_context_get_trace(ctx, trace, len, &len), SIE_STATUS_OK);
        CHECK(trace[0].iteration == 1);
        CHECK(trace[len - 1].iteration == summary.iterations);
        CHECK(trace[0].correspondences == PAIRS);
    }
    free(trace);
}

void test_correspondence_registration(sie_context *ctx) {
    double T[16];
    double padded_source[PAIRS * 4];
    size_t i;

    EXPECT(ctx, sie_context_register_correspondences(ctx, pair_source, 0, pair_target, 3 * sizeof(float), PAIRS,
                                                     NULL, T),
           SIE_STATUS_OK);
    check_pair_result(ctx, T, "float correspondences");

    /* Double precision, padded source stride, refined in place from the identity. */
    for (i = 0; i < PAIRS; i++) {
        memcpy(&padded_source[4 * i], &pair_source_d[3 * i], 3 * sizeof(double));
        padded_source[4 * i + 3] = NAN;
    }
    memcpy(T, IDENTITY, sizeof(T));
    EXPECT(ctx, sie_context_register_correspondences_d(ctx, padded_source, 4 * sizeof(double), pair_target_d, 0,
                                                       PAIRS, T, T),
           SIE_STATUS_OK);
    check_pair_result(ctx, T, "double correspondences");

    /* A later failure discards the stored result. */
    EXPECT(ctx, sie_context_register_correspondences(ctx, pair_source, 0, pair_target, 0, 0, NULL, T),
           SIE_STATUS_TOO_FEW_POINTS);
    test_no_result(ctx);
}

/* expected_starts: the starts run. 1 here for SIE's automatic starts on clouds from the identity
   too: the paper's start is GOOD on its own and corrected the guess locally (within half the
   target's spread, every direction fixed by the corner's planes), so the search ends without a
   rerun from its result. */
static void check_cloud_result(sie_context *ctx, sie_status status, const double T[16], const char *label,
                               uint32_t expected_starts) {
    sie_summary summary;
    double error = max_abs_difference(T, cloud_truth, 16);
    EXPECT(ctx, status, SIE_STATUS_OK);
    if (status != SIE_STATUS_OK) {
        fprintf(stderr, "%s failed\n", label);
        return;
    }
    CHECK(error < 0.01);
    EXPECT(ctx, sie_context_get_summary(ctx, &summary), SIE_STATUS_OK);
    printf("%s: transform error %.2e, inlier fraction %.3f, %u iterations, stop reason %u\n", label, error,
           summary.inlier_fraction, summary.iterations, summary.stop_reason);
    CHECK(summary.source_count == CLOUD);
    CHECK(summary.correspondence_count > CLOUD / 2 && summary.correspondence_count <= CLOUD);
    CHECK(summary.inlier_fraction > 0.5);
    check_quality(&summary, 0, label);
    check_pose_uncertainty(ctx, label);
    CHECK(summary.starts_run == expected_starts);
    if (summary.histogram_count > 0) {
        /* SIE on a clean room corner: a pose every direction of which the three planes fix. */
        CHECK(summary.verdict == SIE_VERDICT_GOOD);
        CHECK(summary.sigma_to_spacing > 0.0);
    } else {
        CHECK(summary.start == SIE_START_KIND_INITIAL_GUESS && summary.agreeing_starts == 1 && summary.margin == 0.0);
    }
}

void test_cloud_registration(sie_context *ctx) {
    double T[16];
    sie_status status;

    EXPECT(ctx, sie_context_set_trace(ctx, false), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_set_max_correspondences(ctx, 0), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_set_metric(ctx, SIE_METRIC_POINT_TO_PLANE), SIE_STATUS_OK);
    status = sie_context_register(ctx, &cloud_source[0].x, CLOUD, sizeof(padded_point), &cloud_target[0].x, CLOUD,
                                  sizeof(padded_point), NULL, T);
    check_cloud_result(ctx, status, T, "float clouds, point-to-plane, 16-byte stride",1);

    status = sie_context_register_with_normals(ctx, &cloud_source[0].x, CLOUD, sizeof(padded_point),
                                               &cloud_target_normals[0].x, CLOUD, sizeof(point_normal),
                                               &cloud_target_normals[0].normal_x, sizeof(point_normal), NULL, T);
    check_cloud_result(ctx, status, T, "float clouds with target normals, 48-byte stride",1);

    EXPECT(ctx, sie_context_set_metric(ctx, SIE_METRIC_POINT_TO_POINT), SIE_STATUS_OK);
    status = sie_context_register_d(ctx, cloud_source_d, CLOUD, 0, cloud_target_d, CLOUD, 0, IDENTITY, T);
    check_cloud_result(ctx, status, T, "double clouds, point-to-point",1);

    /* A baseline cost has no histograms. */
    EXPECT(ctx, sie_context_set_cost_function(ctx, SIE_COST_FUNCTION_HUBER, 0.02), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_set_metric(ctx, SIE_METRIC_POINT_TO_PLANE), SIE_STATUS_OK);
    status = sie_context_register(ctx, &cloud_source[0].x, CLOUD, sizeof(padded_point), &cloud_target[0].x, CLOUD,
                                  sizeof(padded_point), NULL, T);
    check_cloud_result(ctx, status, T, "float clouds, Huber", 1);
    if (status == SIE_STATUS_OK) {
        sie_summary summary;
        sie_model model;
        EXPECT(ctx, sie_context_get_summary(ctx, &summary), SIE_STATUS_OK);
        CHECK(summary.histogram_count == 0);
        EXPECT(ctx, sie_context_get_histogram(ctx, 0, &model, NULL, NULL, NULL, NULL, 0),
               SIE_STATUS_INVALID_ARGUMENT);
    }
    EXPECT(ctx, sie_context_set_cost_function(ctx, SIE_COST_FUNCTION_SIE, 0.0), SIE_STATUS_OK);
}

/* Result of the last registration on ctx: transform, summary and correspondences. */
typedef struct {
    double T[16];
    sie_summary summary;
    int64_t correspondences[CLOUD];
} stored_result;

static void store(sie_context *ctx, const double T[16], stored_result *out) {
    size_t len = 0;
    memcpy(out->T, T, sizeof out->T);
    EXPECT(ctx, sie_context_get_summary(ctx, &out->summary), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_get_correspondences(ctx, out->correspondences, CLOUD, &len), SIE_STATUS_OK);
    CHECK(len == CLOUD);
}

/* Bit for bit: transform, summary and correspondences. */
static int same_result(const stored_result *a, const stored_result *b) {
    return memcmp(a->T, b->T, sizeof a->T) == 0 && memcmp(&a->summary.sigma, &b->summary.sigma, sizeof a->summary.sigma) == 0 &&
           a->summary.iterations == b->summary.iterations && a->summary.inlier_fraction == b->summary.inlier_fraction &&
           a->summary.rmse == b->summary.rmse &&
           memcmp(a->correspondences, b->correspondences, sizeof a->correspondences) == 0;
}

void test_prepared_target(sie_context *ctx) {
    sie_target *target = NULL;
    sie_target *untouched = (sie_target *)&rng_state; /* a sentinel that must not be overwritten */
    sie_target *sentinel = untouched;
    sie_context *other = sie_context_new();
    stored_result direct, prepared, again;
    double T[16], kept[16];
    point_normal bad_normal[3];
    int k;

    /* Both contexts estimate normals from 10 neighbours (test_setters left 12). */
    EXPECT(ctx, sie_context_set_normal_neighbours(ctx, 10), SIE_STATUS_OK);
    /* Errors name the argument; the output is not written. */
    EXPECT(ctx, sie_context_prepare_target(ctx, &cloud_target[0].x, CLOUD, sizeof(padded_point), NULL, 0, NULL),
           SIE_STATUS_NULL_ARGUMENT);
    CHECK(error_contains(ctx, "out_target"));
    EXPECT(ctx, sie_context_prepare_target(ctx, NULL, CLOUD, 0, NULL, 0, &untouched), SIE_STATUS_NULL_ARGUMENT);
    CHECK(error_contains(ctx, "xyz"));
    EXPECT(ctx, sie_context_prepare_target(ctx, &cloud_target[0].x, 2, sizeof(padded_point), NULL, 0, &untouched),
           SIE_STATUS_TOO_FEW_POINTS);
    EXPECT(ctx, sie_context_prepare_target(ctx, &cloud_target[0].x, CLOUD, 5, NULL, 0, &untouched),
           SIE_STATUS_INVALID_ARGUMENT);
    memcpy(bad_normal, cloud_target_normals, sizeof bad_normal);
    bad_normal[1].normal_x = 2.0f;
    EXPECT(ctx, sie_context_prepare_target(ctx, &bad_normal[0].x, 3, sizeof(point_normal), &bad_normal[0].normal_x,
                                           sizeof(point_normal), &untouched),
           SIE_STATUS_INVALID_ARGUMENT);
    CHECK(error_contains(ctx, "normals[1]"));
    CHECK(untouched == sentinel);
    CHECK(sie_target_point_count(NULL) == 0);
    CHECK(sie_target_estimate_normals(NULL, 0) == SIE_STATUS_NULL_ARGUMENT);
    sie_target_free(NULL);

    /* Float target, 16-byte stride: the same result as sie_context_register, twice. */
    EXPECT(ctx, sie_context_set_metric(ctx, SIE_METRIC_POINT_TO_PLANE), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_register(ctx, &cloud_source[0].x, CLOUD, sizeof(padded_point), &cloud_target[0].x, CLOUD,
                                     sizeof(padded_point), NULL, T),
           SIE_STATUS_OK);
    store(ctx, T, &direct);
    EXPECT(ctx, sie_context_prepare_target(ctx, &cloud_target[0].x, CLOUD, sizeof(padded_point), NULL, 0, &target),
           SIE_STATUS_OK);
    CHECK(target != NULL);
    CHECK(sie_target_point_count(target) == CLOUD);
    for (k = 0; k < 2; k++) {
        EXPECT(ctx, sie_context_register_to(ctx, &cloud_source[0].x, CLOUD, sizeof(padded_point), target, NULL, T),
               SIE_STATUS_OK);
        store(ctx, T, &prepared);
        CHECK(same_result(&direct, &prepared));
    }
    /* Another context registers onto the same target. */
    EXPECT(other, sie_context_register_to(other, &cloud_source[0].x, CLOUD, sizeof(padded_point), target, NULL, T),
           SIE_STATUS_OK);
    store(other, T, &again);
    CHECK(same_result(&direct, &again));
    /* Normals estimated up front change nothing. */
    CHECK(sie_target_estimate_normals(target, 2) == SIE_STATUS_OK);
    CHECK(sie_target_estimate_normals(target, 5000) == SIE_STATUS_INVALID_ARGUMENT);
    EXPECT(ctx, sie_context_register_to(ctx, &cloud_source[0].x, CLOUD, sizeof(padded_point), target, IDENTITY, T),
           SIE_STATUS_OK);
    store(ctx, T, &again);
    CHECK(same_result(&direct, &again));
    /* A config whose normals differ from the target's is refused, outputs untouched. */
    memcpy(kept, T, sizeof kept);
    EXPECT(ctx, sie_context_set_normal_neighbours(ctx, 20), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_register_to(ctx, &cloud_source[0].x, CLOUD, sizeof(padded_point), target, NULL, T),
           SIE_STATUS_INVALID_ARGUMENT);
    CHECK(error_contains(ctx, "normal_neighbours"));
    CHECK(memcmp(kept, T, sizeof kept) == 0);
    EXPECT(ctx, sie_context_get_summary(ctx, &again.summary), SIE_STATUS_NO_RESULT);
    EXPECT(ctx, sie_context_set_normal_neighbours(ctx, 10), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_register_to(ctx, &cloud_source[0].x, CLOUD, sizeof(padded_point), NULL, NULL, T),
           SIE_STATUS_NULL_ARGUMENT);
    CHECK(error_contains(ctx, "target"));
    EXPECT(ctx, sie_context_register_to(ctx, NULL, CLOUD, 0, target, NULL, T), SIE_STATUS_NULL_ARGUMENT);
    EXPECT(ctx, sie_context_register_to(ctx, &cloud_source[0].x, 0, sizeof(padded_point), target, NULL, T),
           SIE_STATUS_TOO_FEW_POINTS);
    sie_target_free(target);

    /* Given normals (48-byte stride). */
    EXPECT(ctx, sie_context_register_with_normals(ctx, &cloud_source[0].x, CLOUD, sizeof(padded_point),
                                                  &cloud_target_normals[0].x, CLOUD, sizeof(point_normal),
                                                  &cloud_target_normals[0].normal_x, sizeof(point_normal), NULL, T),
           SIE_STATUS_OK);
    store(ctx, T, &direct);
    EXPECT(ctx, sie_context_prepare_target(ctx, &cloud_target_normals[0].x, CLOUD, sizeof(point_normal),
                                           &cloud_target_normals[0].normal_x, sizeof(point_normal), &target),
           SIE_STATUS_OK);
    EXPECT(ctx, sie_context_register_to(ctx, &cloud_source[0].x, CLOUD, sizeof(padded_point), target, NULL, T),
           SIE_STATUS_OK);
    store(ctx, T, &prepared);
    CHECK(same_result(&direct, &prepared));
    sie_target_free(target);

    /* Double clouds, point-to-point. */
    EXPECT(ctx, sie_context_set_metric(ctx, SIE_METRIC_POINT_TO_POINT), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_register_d(ctx, cloud_source_d, CLOUD, 0, cloud_target_d, CLOUD, 0, NULL, T), SIE_STATUS_OK);
    store(ctx, T, &direct);
    EXPECT(ctx, sie_context_prepare_target_d(ctx, cloud_target_d, CLOUD, 0, NULL, 0, &target), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_register_to_d(ctx, cloud_source_d, CLOUD, 0, target, NULL, T), SIE_STATUS_OK);
    store(ctx, T, &prepared);
    CHECK(same_result(&direct, &prepared));
    check_cloud_result(ctx, SIE_STATUS_OK, T, "double source onto a prepared double target, point-to-point",1);
    sie_target_free(target);
    EXPECT(ctx, sie_context_set_metric(ctx, SIE_METRIC_POINT_TO_PLANE), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_set_normal_neighbours(ctx, 12), SIE_STATUS_OK);
    sie_context_free(other);
}

/* Cancels when the iteration reaches *(uint32_t *)user_data. */
static int32_t cancel_at_iteration(void *user_data, const sie_trace_entry *entry) {
    return entry->iteration >= *(const uint32_t *)user_data ? 1 : 0;
}

/* Records what a viewer would: every iteration's transform and inlier fraction. */
typedef struct {
    uint32_t calls;
    uint32_t last_iteration;
    double last_transform[16];
    double last_inlier_fraction;
    int rigid; /* every transform had last row 0 0 0 1 */
} progress_log;

static int32_t record_progress(void *user_data, const sie_trace_entry *entry) {
    progress_log *log = (progress_log *)user_data;
    log->calls++;
    log->last_iteration = entry->iteration;
    memcpy(log->last_transform, entry->transform, sizeof(log->last_transform));
    log->last_inlier_fraction = entry->inlier_fraction;
    log->rigid &= entry->transform[12] == 0.0 && entry->transform[13] == 0.0 && entry->transform[14] == 0.0 &&
                  entry->transform[15] == 1.0;
    return 0;
}

/* The progress callback carries the transform reached by each update (row-major), the recorded
 * trace has the same transforms, and the inlier fraction means what the summary's means. From
 * the initial guess alone the last update is the returned transform. With the automatic starts
 * every start's updates are reported, in order and numbered on (iterations counts them all), and
 * the returned transform is one of them: the last update of the start that won. */
void test_progress_transform(sie_context *ctx) {
    double T[16];
    progress_log log;
    sie_summary summary;
    sie_trace_entry *trace;
    size_t len = 0, i;
    int automatic;

    EXPECT(ctx, sie_context_set_metric(ctx, SIE_METRIC_POINT_TO_PLANE), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_set_trace(ctx, true), SIE_STATUS_OK);
    for (automatic = 0; automatic <= 1; automatic++) {
        const char *label = automatic ? "automatic starts" : "initial guess";
        memset(&log, 0, sizeof(log));
        log.rigid = 1;
        EXPECT(ctx, sie_context_set_starts(ctx, automatic ? SIE_STARTS_AUTOMATIC : SIE_STARTS_INITIAL_GUESS),
               SIE_STATUS_OK);
        EXPECT(ctx, sie_context_set_progress_callback(ctx, record_progress, &log), SIE_STATUS_OK);
        EXPECT(ctx,
               sie_context_register(ctx, &cloud_source[0].x, CLOUD, sizeof(padded_point), &cloud_target[0].x, CLOUD,
                                    sizeof(padded_point), NULL, T),
               SIE_STATUS_OK);
        EXPECT(ctx, sie_context_set_progress_callback(ctx, NULL, NULL), SIE_STATUS_OK);
        EXPECT(ctx, sie_context_get_summary(ctx, &summary), SIE_STATUS_OK);
        CHECK(log.calls == summary.iterations && log.last_iteration == summary.iterations);
        CHECK(log.rigid);
        CHECK(max_abs_difference(T, cloud_truth, 16) < 0.01);
        check_quality(&summary, 0, label);
        CHECK(summary.verdict == SIE_VERDICT_GOOD);
        if (automatic) {
            /* The paper's start, GOOD on its own and a local correction of the guess: no other
               start and no rerun. */
            CHECK(summary.starts_run == 1 && summary.agreeing_starts == 1);
        } else {
            /* It travelled more than 10 sigma from the identity, but within half the corner's
               spread with every direction fixed: a local correction, not run again. */
            CHECK(summary.starts_run == 1 && summary.start == SIE_START_KIND_INITIAL_GUESS &&
                  summary.agreeing_starts == 1 && summary.margin == 0.0 && summary.runner_up_significance == 0.0);
            CHECK(max_abs_difference(log.last_transform, T, 16) == 0.0);
            /* Converged: the last update's weights and the result's probabilities barely differ. */
            CHECK(fabs(log.last_inlier_fraction - summary.inlier_fraction) < 0.01);
        }
        printf("progress (%s): %u calls, last inlier fraction %.4f, summary %.4f\n", label, log.calls,
               log.last_inlier_fraction, summary.inlier_fraction);

        EXPECT(ctx, sie_context_get_trace(ctx, NULL, 0, &len), SIE_STATUS_OK);
        CHECK(len == summary.iterations);
        trace = (sie_trace_entry *)calloc(len + 1, sizeof(sie_trace_entry));
        if (trace != NULL && len >= 2) {
            int returned_is_an_update = 0, numbered_on = 1;
            EXPECT(ctx, sie_context_get_trace(ctx, trace, len, &len), SIE_STATUS_OK);
            for (i = 0; i < len; i++) {
                numbered_on &= trace[i].iteration == i + 1;
                returned_is_an_update |= max_abs_difference(trace[i].transform, T, 16) == 0.0;
            }
            CHECK(numbered_on);
            CHECK(returned_is_an_update);
            CHECK(max_abs_difference(trace[len - 1].transform, log.last_transform, 16) == 0.0);
            if (!automatic) {
                CHECK(max_abs_difference(trace[len - 1].transform, T, 16) == 0.0);
            }
            /* The first update already moved away from the identity guess. */
            CHECK(max_abs_difference(trace[0].transform, IDENTITY, 16) > 1e-4);
            CHECK(trace[len - 1].inlier_fraction == log.last_inlier_fraction);
        }
        free(trace);
    }
    EXPECT(ctx, sie_context_set_trace(ctx, false), SIE_STATUS_OK);
}

/* Pairs without any relation (both ends uniform in a cube): no pose is supported. Then the
 * same with only the initial guess, and the real pairs from it: one start, nothing to compare. */
void test_verdicts(sie_context *ctx) {
    static float unrelated[PAIRS * 3];
    double T[16];
    sie_summary summary;
    size_t i;

    for (i = 0; i < PAIRS * 3; i++) {
        unrelated[i] = (float)uniform(-1.0, 1.0);
    }
    EXPECT(ctx, sie_context_register_correspondences(ctx, pair_source, 0, unrelated, 0, PAIRS, NULL, T),
           SIE_STATUS_OK);
    EXPECT(ctx, sie_context_get_summary(ctx, &summary), SIE_STATUS_OK);
    check_quality(&summary, 1, "unrelated pairs");
    CHECK(summary.verdict == SIE_VERDICT_UNSUPPORTED);
    CHECK(summary.significance == 0.0);
    CHECK(summary.hypotheses > 0);

    EXPECT(ctx, sie_context_set_starts(ctx, SIE_STARTS_INITIAL_GUESS), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_register_correspondences(ctx, pair_source, 0, unrelated, 0, PAIRS, NULL, T),
           SIE_STATUS_OK);
    EXPECT(ctx, sie_context_get_summary(ctx, &summary), SIE_STATUS_OK);
    check_quality(&summary, 1, "unrelated pairs, initial guess only");
    CHECK(summary.verdict == SIE_VERDICT_UNSUPPORTED);
    CHECK(summary.hypotheses == 0 && summary.starts_run == 1);

    EXPECT(ctx, sie_context_register_correspondences(ctx, pair_source, 0, pair_target, 0, PAIRS, NULL, T),
           SIE_STATUS_OK);
    EXPECT(ctx, sie_context_get_summary(ctx, &summary), SIE_STATUS_OK);
    check_quality(&summary, 1, "pairs, initial guess only");
    CHECK(max_abs_difference(T, pair_truth, 16) < 0.01);
    CHECK(summary.verdict == SIE_VERDICT_GOOD);
    CHECK(summary.start == SIE_START_KIND_INITIAL_GUESS && summary.hypotheses == 0 && summary.starts_run == 1 &&
          summary.agreeing_starts == 1 && summary.margin == 0.0 && summary.runner_up_significance == 0.0);
    EXPECT(ctx, sie_context_set_starts(ctx, SIE_STARTS_AUTOMATIC), SIE_STATUS_OK);
}

void test_cancellation_and_non_finite(sie_context *ctx) {
    double T[16];
    uint32_t stop_at = 2;
    sie_summary summary;
    float with_nan[PAIRS * 3];
    double probabilities[PAIRS];
    int64_t correspondences[PAIRS];

    /* A progress callback that asks to stop: CANCELLED, with the transform so far written. */
    EXPECT(ctx, sie_context_set_progress_callback(ctx, cancel_at_iteration, &stop_at), SIE_STATUS_OK);
    memset(T, 0, sizeof(T));
    EXPECT(ctx, sie_context_register_correspondences(ctx, pair_source, 0, pair_target, 0, PAIRS, NULL, T),
           SIE_STATUS_CANCELLED);
    CHECK(T[15] == 1.0);
    EXPECT(ctx, sie_context_get_summary(ctx, &summary), SIE_STATUS_OK);
    CHECK(summary.stop_reason == SIE_STOP_REASON_CANCELLED && summary.iterations == 2 && !summary.converged);
    EXPECT(ctx, sie_context_set_progress_callback(ctx, NULL, NULL), SIE_STATUS_OK);

    /* A cancel request made before a run stops it after its first iteration, once. */
    CHECK(sie_context_cancel(ctx) == SIE_STATUS_OK);
    EXPECT(ctx, sie_context_register_correspondences(ctx, pair_source, 0, pair_target, 0, PAIRS, NULL, T),
           SIE_STATUS_CANCELLED);
    EXPECT(ctx, sie_context_get_summary(ctx, &summary), SIE_STATUS_OK);
    CHECK(summary.iterations == 1);
    EXPECT(ctx, sie_context_register_correspondences(ctx, pair_source, 0, pair_target, 0, PAIRS, NULL, T),
           SIE_STATUS_OK);

    /* NaN points: rejected by index, or skipped on request with probability 0 and no match. */
    memcpy(with_nan, pair_source, sizeof(with_nan));
    with_nan[3 * 7 + 1] = NAN;
    EXPECT(ctx, sie_context_register_correspondences(ctx, with_nan, 0, pair_target, 0, PAIRS, NULL, T),
           SIE_STATUS_NON_FINITE_INPUT);
    CHECK(error_contains(ctx, "source_xyz[7]"));
    EXPECT(ctx, sie_context_set_skip_non_finite(ctx, true), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_register_correspondences(ctx, with_nan, 0, pair_target, 0, PAIRS, NULL, T),
           SIE_STATUS_OK);
    CHECK(max_abs_difference(T, pair_truth, 16) < 0.01);
    EXPECT(ctx, sie_context_get_inlier_probabilities(ctx, probabilities, PAIRS, NULL), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_get_correspondences(ctx, correspondences, PAIRS, NULL), SIE_STATUS_OK);
    CHECK(probabilities[7] == 0.0 && correspondences[7] == -1 && correspondences[8] == 8);
    EXPECT(ctx, sie_context_set_skip_non_finite(ctx, false), SIE_STATUS_OK);
}

/* Odometry: the target's scan is the first frame (the world), the source's the second, whose pose
 * is then cloud_truth; a repeat and a refused frame change nothing the caller holds. */
void test_odometry(sie_context *ctx) {
    sie_odometry *odometry = NULL;
    sie_odometry *untouched = (sie_odometry *)&rng_state; /* a sentinel that must not be overwritten */
    double pose[16], kept[16], stored[16];
    uint32_t status = 99;
    int k;

    for (k = 0; k < 16; k++) {
        pose[k] = SENTINEL;
    }
    EXPECT(ctx, sie_context_odometry_new(ctx, NULL), SIE_STATUS_NULL_ARGUMENT);
    CHECK(error_contains(ctx, "out_odometry"));
    EXPECT(ctx, sie_context_set_metric(ctx, SIE_METRIC_POINT_TO_PLANE), SIE_STATUS_OK);
    EXPECT(ctx, sie_context_odometry_new(ctx, &odometry), SIE_STATUS_OK);
    CHECK(odometry != NULL && odometry != untouched);
    EXPECT(ctx, sie_context_odometry_register_frame(ctx, NULL, &cloud_target[0].x, CLOUD, sizeof(padded_point), pose,
                                                    &status),
           SIE_STATUS_NULL_ARGUMENT);
    CHECK(error_contains(ctx, "odometry"));
    EXPECT(ctx, sie_context_odometry_register_frame(ctx, odometry, &cloud_target[0].x, CLOUD, sizeof(padded_point),
                                                    NULL, &status),
           SIE_STATUS_NULL_ARGUMENT);
    CHECK(status == 99 && all_equal(pose, 16, SENTINEL));

    EXPECT(ctx, sie_context_odometry_register_frame(ctx, odometry, &cloud_target[0].x, CLOUD, sizeof(padded_point), pose,
                                                    &status),
           SIE_STATUS_OK);
    CHECK(status == SIE_FRAME_STATUS_FIRST);
    CHECK(max_abs_difference(pose, IDENTITY, 16) == 0.0);
    EXPECT(ctx, sie_context_odometry_register_frame_d(ctx, odometry, cloud_source_d, CLOUD, 0, pose, &status),
           SIE_STATUS_OK);
    CHECK(status == SIE_FRAME_STATUS_ACCEPTED);
    CHECK(max_abs_difference(pose, cloud_truth, 16) < 0.01);
    EXPECT(ctx, sie_odometry_pose(odometry, stored), SIE_STATUS_OK);
    CHECK(max_abs_difference(pose, stored, 16) == 0.0);

    /* The same frame again: REPEATED, the pose not written; two points: refused, nothing written. */
    for (k = 0; k < 16; k++) {
        kept[k] = pose[k];
        pose[k] = SENTINEL;
    }
    EXPECT(ctx, sie_context_odometry_register_frame_d(ctx, odometry, cloud_source_d, CLOUD, 0, pose, &status),
           SIE_STATUS_OK);
    CHECK(status == SIE_FRAME_STATUS_REPEATED && all_equal(pose, 16, SENTINEL));
    status = 99;
    EXPECT(ctx, sie_context_odometry_register_frame(ctx, odometry, &cloud_source[0].x, 2, sizeof(padded_point), pose,
                                                    &status),
           SIE_STATUS_TOO_FEW_POINTS);
    CHECK(status == 99 && all_equal(pose, 16, SENTINEL));
    EXPECT(ctx, sie_odometry_pose(odometry, stored), SIE_STATUS_OK);
    CHECK(max_abs_difference(kept, stored, 16) == 0.0);
    EXPECT(ctx, sie_odometry_pose(NULL, stored), SIE_STATUS_NULL_ARGUMENT);
    sie_odometry_skip_frame(odometry);
    sie_odometry_skip_frame(NULL);
    sie_odometry_free(odometry);
    sie_odometry_free(NULL);
}
