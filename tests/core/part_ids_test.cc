// The ids that cross stores (part_ids.h): a part's vertex id, the map into the merged store and
// the sealed output's global id are types of their own, as small as the raw ids.
#include "part_ids.h"

#include <cstdint>
#include <span>
#include <type_traits>

#include "gtest/gtest.h"
#include "mesh_store.h"
#include "sealer.h"
#include "simplifier.h"
#include "simplifier_access.h"
#include "tandem/types.h"

namespace tandem {
namespace {

// A store's own id does not pass for another part's, nor for a global one, nor back.
static_assert(!std::is_convertible_v<VertexId, PartVertex>);
static_assert(!std::is_convertible_v<PartVertex, VertexId>);
static_assert(!std::is_convertible_v<VertexId, GlobalId>);
static_assert(!std::is_convertible_v<GlobalId, VertexId>);
static_assert(!std::is_convertible_v<PartVertex, GlobalId>);
// The merge and the sealer take them where ids of two stores meet.
static_assert(!std::is_invocable_v<decltype(&SimplifierSeamAccess::AdoptVertex), Simplifier&,
                                   const Simplifier&, VertexId, VertexId, bool>);
static_assert(std::is_invocable_v<decltype(&SimplifierSeamAccess::AdoptVertex), Simplifier&,
                                  const Simplifier&, PartVertex, VertexId, bool>);
static_assert(!std::is_invocable_v<decltype(&SimplifierSeamAccess::AdoptQueues), Simplifier&,
                                   const Simplifier&, std::span<const VertexId>>);
static_assert(
    !std::is_invocable_v<decltype(&Sealer::FreezeShared), Sealer&, VertexId, uint32_t, double>);
static_assert(!std::is_invocable_v<decltype(&Sealer::Absorb), Sealer&, const Sealer&,
                                   std::span<const VertexId>, std::span<const VertexId>>);
// Zero cost: the same size and the same bits.
static_assert(sizeof(PartVertex) == sizeof(VertexId) && sizeof(GlobalId) == sizeof(uint32_t));
static_assert(std::is_trivially_copyable_v<PartVertex> && std::is_trivially_copyable_v<GlobalId>);

TEST(PartIdsTest, MapSendsAPartsIdsToTheMergedStoresAndUnmappedToInvalid) {
  PartVertexMap map;
  map.Reset(4);
  ASSERT_EQ(map.size(), 4u);
  map[PartVertex{2}] = 7;
  EXPECT_EQ(map[PartVertex{2}], 7u);
  for (VertexId v : {0u, 1u, 3u}) EXPECT_EQ(map[PartVertex{v}], kInvalid) << v;
  PartVertexMap other;
  other.Reset(1);
  map.swap(other);
  EXPECT_EQ(map.size(), 1u);
  EXPECT_EQ(other[PartVertex{2}], 7u);
  map.Reset(3);  // a new part: nothing mapped
  EXPECT_EQ(map[PartVertex{0}], kInvalid);
}

TEST(PartIdsTest, GlobalIdsKeepTheirValueAndNoneIsInvalid) {
  EXPECT_EQ(Value(GlobalId{12}), 12u);
  EXPECT_EQ(Value(kNoGlobalId), kInvalid);
  EXPECT_EQ(InPart(PartVertex{5}), 5u);
  EXPECT_NE(GlobalId{0}, kNoGlobalId);
}

}  // namespace
}  // namespace tandem
