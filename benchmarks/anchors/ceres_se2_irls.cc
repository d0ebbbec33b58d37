// A timing anchor for benchmarks/solve_floor.py: the pose graphs a map's rebuild optimises, solved
// by Ceres with C++ SE(2) costs (one residual block per edge, automatic derivatives), in the same
// schedule as cogmap_core/optimizer.py solves them on a bag: without loop closures one solve; with
// them, rounds of iteratively reweighted least squares (Geman-McClure weights of the loop
// closures, fixed for at most `irls_iterations` Ceres iterations, until the robust cost changes by
// at most `tolerance` of itself), the other edges under Huber. It measures what cogmap's Python
// cost functions cost against compiled ones; it is not part of cogmap (cogmap installs with no
// compiler) and is built by the benchmark only where a C++ compiler and Ceres' headers exist.
//
//   ceres_se2_irls GRAPHS.bin
//
// GRAPHS.bin, little-endian float64 throughout: the header [count, huber_scale, loop_scale,
// tolerance, irls_iterations, max_iterations, function_tolerance], then per graph [n, m], the
// poses (n x 3), fixed (n), edge ends (m x 2), measurements (m x 3), square roots of the diagonal
// information (m x 3) and loop flags (m). Prints one line:
//   solves S iterations I setup_ms A solve_ms B

#include <ceres/ceres.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <vector>

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kMaxReweightings = 50;
constexpr double kDropWeight = 1e-6;

// The whitened g2o residual of an edge i -> j, times the square root of a weight set between
// solves (a loop closure's IRLS weight; 1 for the other edges).
struct EdgeCost {
  double z[3];
  double root_information[3];
  const double* root_weight;

  template <typename T>
  bool operator()(const T* a, const T* b, T* r) const {
    const T c = cos(a[2]), s = sin(a[2]);
    const T dx = b[0] - a[0], dy = b[1] - a[1];
    const T u = c * dx + s * dy - z[0], v = c * dy - s * dx - z[1];
    const double cz = std::cos(z[2]), sz = std::sin(z[2]);
    T angle = b[2] - a[2] - z[2];
    while (angle >= T(kPi)) angle -= T(2.0 * kPi);
    while (angle < T(-kPi)) angle += T(2.0 * kPi);
    const double w = *root_weight;
    r[0] = w * root_information[0] * (cz * u + sz * v);
    r[1] = w * root_information[1] * (-sz * u + cz * v);
    r[2] = w * root_information[2] * angle;
    return true;
  }
};

struct Graph {
  int n = 0, m = 0;
  std::vector<double> poses, fixed, ends, z, root_information, loop;
};

bool read_doubles(FILE* file, double* out, size_t count) {
  return std::fread(out, sizeof(double), count, file) == count;
}

bool read_graph(FILE* file, Graph* g) {
  double size[2];
  if (!read_doubles(file, size, 2)) return false;
  g->n = static_cast<int>(size[0]);
  g->m = static_cast<int>(size[1]);
  g->poses.resize(3 * g->n);
  g->fixed.resize(g->n);
  g->ends.resize(2 * g->m);
  g->z.resize(3 * g->m);
  g->root_information.resize(3 * g->m);
  g->loop.resize(g->m);
  return read_doubles(file, g->poses.data(), g->poses.size()) &&
         read_doubles(file, g->fixed.data(), g->fixed.size()) &&
         read_doubles(file, g->ends.data(), g->ends.size()) &&
         read_doubles(file, g->z.data(), g->z.size()) &&
         read_doubles(file, g->root_information.data(), g->root_information.size()) &&
         read_doubles(file, g->loop.data(), g->loop.size());
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s GRAPHS.bin\n", argv[0]);
    return 2;
  }
  FILE* file = std::fopen(argv[1], "rb");
  double header[7];
  if (file == nullptr || !read_doubles(file, header, 7)) {
    std::fprintf(stderr, "cannot read %s\n", argv[1]);
    return 1;
  }
  const int count = static_cast<int>(header[0]);
  const double huber_scale = header[1], loop_scale = header[2], tolerance = header[3];
  const int irls_iterations = static_cast<int>(header[4]);
  const int max_iterations = static_cast<int>(header[5]);
  const double c2 = loop_scale * loop_scale;
  long solves = 0, iterations = 0;
  double setup_s = 0.0, solve_s = 0.0;
  for (int index = 0; index < count; ++index) {
    Graph g;
    if (!read_graph(file, &g)) {
      std::fprintf(stderr, "%s: graph %d is truncated\n", argv[1], index);
      return 1;
    }
    const auto started = std::chrono::steady_clock::now();
    ceres::Problem::Options problem_options;
    problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    ceres::Problem problem(problem_options);
    ceres::HuberLoss huber(huber_scale);
    std::vector<double> root_weight(g.m, 1.0);
    const double one = 1.0;
    std::vector<EdgeCost> unweighted(g.m);  // each edge's cost at weight 1: chi^2 between rounds
    bool any_loop = false;
    for (int k = 0; k < g.m; ++k) {
      EdgeCost& cost = unweighted[k];
      for (int a = 0; a < 3; ++a) {
        cost.z[a] = g.z[3 * k + a];
        cost.root_information[a] = g.root_information[3 * k + a];
      }
      cost.root_weight = &one;
      const int i = static_cast<int>(g.ends[2 * k]), j = static_cast<int>(g.ends[2 * k + 1]);
      if (i == j) continue;
      const bool loop = g.loop[k] != 0.0;
      any_loop = any_loop || loop;
      auto* weighted = new EdgeCost(cost);
      weighted->root_weight = &root_weight[k];
      problem.AddResidualBlock(new ceres::AutoDiffCostFunction<EdgeCost, 3, 3, 3>(weighted),
                               loop ? nullptr : &huber, &g.poses[3 * i], &g.poses[3 * j]);
    }
    bool gauge = false;
    for (int i = 0; i < g.n; ++i) {
      if (g.fixed[i] != 0.0 && problem.HasParameterBlock(&g.poses[3 * i])) {
        problem.SetParameterBlockConstant(&g.poses[3 * i]);
        gauge = true;
      }
    }
    if (!gauge && g.n > 0 && problem.HasParameterBlock(&g.poses[0])) {
      problem.SetParameterBlockConstant(&g.poses[0]);
    }
    ceres::Solver::Options options;
    options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
    options.num_threads = 1;
    options.function_tolerance = header[6];
    options.initial_trust_region_radius = 1e8;
    options.logging_type = ceres::SILENT;
    const auto built = std::chrono::steady_clock::now();
    setup_s += std::chrono::duration<double>(built - started).count();
    auto solve = [&](int limit) {
      options.max_num_iterations = limit;
      ceres::Solver::Summary summary;
      ceres::Solve(options, &problem, &summary);
      ++solves;
      iterations += summary.num_successful_steps + summary.num_unsuccessful_steps - 1;
    };
    if (problem.NumResidualBlocks() > 0 && !any_loop) {
      solve(max_iterations);
    } else if (any_loop) {
      double previous = std::numeric_limits<double>::infinity();
      for (int round = 0; round < kMaxReweightings; ++round) {
        // chi^2 of every edge at the current poses (weight 1), the robust cost, the new weights
        double cost = 0.0;
        std::vector<double> chi2(g.m, 0.0);
        for (int k = 0; k < g.m; ++k) {
          const int i = static_cast<int>(g.ends[2 * k]), j = static_cast<int>(g.ends[2 * k + 1]);
          double r[3];
          unweighted[k](&g.poses[3 * i], &g.poses[3 * j], r);
          const double s = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
          chi2[k] = s;
          if (g.loop[k] != 0.0) {
            cost += c2 * s / (c2 + s);
          } else {
            cost += s <= huber_scale * huber_scale ? s
                                                   : 2.0 * huber_scale * std::sqrt(s) -
                                                         huber_scale * huber_scale;
          }
        }
        if (std::fabs(previous - cost) <= tolerance * cost) break;
        previous = cost;
        for (int k = 0; k < g.m; ++k) {
          if (g.loop[k] == 0.0) continue;
          const double w = (c2 / (c2 + chi2[k])) * (c2 / (c2 + chi2[k]));
          root_weight[k] = w < kDropWeight ? 0.0 : std::sqrt(w);
        }
        solve(irls_iterations);
      }
    }
    solve_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - built).count();
  }
  std::printf("solves %ld iterations %ld setup_ms %.3f solve_ms %.3f\n", solves, iterations,
              1e3 * setup_s, 1e3 * solve_s);
  return 0;
}
