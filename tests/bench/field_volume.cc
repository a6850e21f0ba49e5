// field_volume: writes one of the reduction sweep's fields not made with the paper's formulas
// (signed distance maps, smoothed masks and CT-like intensities of the generated shapes, the
// rounded cube as an approximate distance; fields_lib.h says what each is), float32.
//   field_volume SHAPE KIND --size N --out V.{json,nrrd} [--sigma S] [--noise HU] [--seed S]
#include <cstdio>
#include <string>

#include "bench_common.h"
#include "fields_lib.h"

int main(int argc, char** argv) {
  if (argc < 3 || argv[1][0] == '-' || argv[2][0] == '-') {
    std::fprintf(stderr,
                 "usage: field_volume {sphere,pillowbox,link,roundcube} {sdf,mask,ct,field} "
                 "--size N --out V.{json,nrrd} [--sigma S] [--noise HU] [--seed S]\n");
    return 2;
  }
  fields::FieldSpec spec;
  spec.shape = argv[1];
  spec.kind = argv[2];
  auto flags = bench::ParseFlags(argc - 2, argv + 2);
  const std::string out = bench::Require(flags, "out");
  try {
    spec.size = std::stoi(bench::Require(flags, "size"));
    if (flags.count("sigma")) spec.sigma = std::stod(flags["sigma"]);
    if (flags.count("noise")) spec.noise = std::stod(flags["noise"]);
    if (flags.count("seed")) spec.seed = std::stoull(flags["seed"]);
  } catch (const std::exception&) {
    bench::Die("--size, --sigma, --noise and --seed take numbers");
  }
  auto field = fields::MakeField(spec);
  if (!field.ok()) bench::Die(std::string(field.status().message()));
  if (absl::Status s = fields::WriteField(out, spec, *field); !s.ok()) {
    bench::Die(std::string(s.message()));
  }
  return 0;
}
