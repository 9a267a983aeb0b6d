// The small synthetic floor that tests (and the fuzzers' seed maker) render in memory.
// Without gtest, so that non-test programs may use it.
#pragma once

#include "ground_texture_bow/eval/synth/generator.h"

namespace gtbow {
namespace testing_util {

// width x height metres of the default surface with its database images (day 0),
// `train_images` training images from a separate area, and no queries.
inline synth::Scene SmallScene(double width, double height, int train_images) {
  synth::SynthOptions so;
  so.area_width = width;
  so.area_height = height;
  so.train_images = train_images;
  so.queries_per_split = 0;
  return synth::Scene(so);
}

}  // namespace testing_util
}  // namespace gtbow
