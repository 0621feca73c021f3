//! AprilTag tag36h11 boards: the family's codes and their printed layout, exactly as
//! AprilTag 3 (AprilRobotics/apriltag, `tag36h11.c` and `apriltag_to_image`) draws them.
//!
//! # Printed layout
//!
//! A tag36h11 board is a grid of 10×10 equal cells (`total_width = 10` in AprilTag):
//!
//! - ring 0 (the outermost cells): white border,
//! - ring 1: black border (`width_at_border = 8`: the black square is 8×8 cells),
//! - the inner 6×6 cells: the 36 data bits, white where the bit is 1.
//!
//! Cells are addressed `[row][col]`: row 0 is the top of the printed tag, col 0 its left.
//! Bit `i` of the layout (`i = 0` is the code's most significant bit, bit 35) is drawn in
//! the cell `(row, col) = (TAG36H11_BIT_Y[i] + 1, TAG36H11_BIT_X[i] + 1)`; the `BIT_X`/`BIT_Y`
//! tables are AprilTag's, given in the 8×8 black-square grid, hence the `+ 1`.
//!
//! AprilTag's *tag size* is the edge of the black square (8 cells), not of the board:
//! a board printed for tag size `s` is `1.25·s` wide ([`BOARD_PER_TAG_SIZE`]).
//!
//! # Board coordinates
//!
//! `(u, v) ∈ [0, 1]²` cover the whole 10×10 board including the white border; `u` runs
//! right and `v` down as printed. The black square is `u, v ∈ [0.1, 0.9]`.
//!
//! # Tag frame (AprilTag 3 and `apriltag_ros` convention)
//!
//! Origin at the centre of the tag, `x` right and `y` down as printed, `z` into the tag
//! (so the printed face is the plane `z = 0` and faces `-z`, towards a viewer reading it).
//! Board coordinates map to it by [`board_to_tag_frame`]:
//! `(x, y, z) = ((u − 0.5)·1.25·s, (v − 0.5)·1.25·s, 0)`.
//!
//! # Detector corner order
//!
//! AprilTag 3 reports a detection's corners (`apriltag_detection_t::p`, the `apriltag`
//! crate's `Detection::corners()`) in this order, which the tests check against the
//! real detector; they follow the tag, not the image (a tag seen upside down still
//! starts with its own bottom-left corner):
//!
//! | index | printed corner | tag frame `(x, y)` | board `(u, v)` |
//! |-------|----------------|--------------------|----------------|
//! | 0     | bottom-left    | `(−s/2, +s/2)`     | `(0.1, 0.9)`   |
//! | 1     | bottom-right   | `(+s/2, +s/2)`     | `(0.9, 0.9)`   |
//! | 2     | top-right      | `(+s/2, −s/2)`     | `(0.9, 0.1)`   |
//! | 3     | top-left       | `(−s/2, −s/2)`     | `(0.1, 0.1)`   |
//!
//! These are the object points of AprilTag's `estimate_tag_pose` ([`tag_corners`]), so a
//! pose solved from them is `camera_from_tag` in the frame above. The detector's pixel
//! convention: pixel `(i, j)` covers `[i, i+1) × [j, j+1)`, its centre is at
//! `(i + 0.5, j + 0.5)`.

/// Number of codes in the tag36h11 family (ids `0..587`).
pub const TAG36H11_NUM_CODES: usize = 587;

/// Cells across a whole tag36h11 board including the white border (AprilTag's
/// `total_width`).
pub const TAG36H11_TOTAL_CELLS: usize = 10;

/// Cells across the black square (AprilTag's `width_at_border`); the tag size.
pub const TAG36H11_BORDER_CELLS: usize = 8;

/// Edge of the whole board (with its white border) per unit of AprilTag tag size.
pub const BOARD_PER_TAG_SIZE: f64 = 1.25;

/// Reflectance of the printed black cells.
pub const TAG_BLACK_ALBEDO: f32 = 0.05;

/// Reflectance of the white paper.
pub const TAG_WHITE_ALBEDO: f32 = 0.85;

/// Column of each data bit in the 8×8 black-square grid (AprilTag 3 `tag36h11_create`),
/// most significant bit first.
pub const TAG36H11_BIT_X: [u8; 36] = [
    1, 2, 3, 4, 5, 2, 3, 4, 3, 6, 6, 6, 6, 6, 5, 5, 5, 4, 6, 5, 4, 3, 2, 5, 4, 3, 4, 1, 1, 1, 1, 1,
    2, 2, 2, 3,
];

/// Row of each data bit in the 8×8 black-square grid (AprilTag 3 `tag36h11_create`),
/// most significant bit first.
pub const TAG36H11_BIT_Y: [u8; 36] = [
    1, 1, 1, 1, 1, 2, 2, 2, 3, 1, 2, 3, 4, 5, 2, 3, 4, 3, 6, 6, 6, 6, 6, 5, 5, 5, 4, 6, 5, 4, 3, 2,
    5, 4, 3, 4,
];

/// The 587 tag36h11 codes, copied from AprilTag 3's `tag36h11.c` (`codedata`); index = id.
pub const TAG36H11_CODES: [u64; TAG36H11_NUM_CODES] = [
    0x0000000d7e00984b,
    0x0000000dda664ca7,
    0x0000000dc4a1c821,
    0x0000000e17b470e9,
    0x0000000ef91d01b1,
    0x0000000f429cdd73,
    0x000000005da29225,
    0x00000001106cba43,
    0x0000000223bed79d,
    0x000000021f51213c,
    0x000000033eb19ca6,
    0x00000003f76eb0f8,
    0x0000000469a97414,
    0x000000045dcfe0b0,
    0x00000004a6465f72,
    0x000000051801db96,
    0x00000005eb946b4e,
    0x000000068a7cc2ec,
    0x00000006f0ba2652,
    0x000000078765559d,
    0x000000087b83d129,
    0x000000086cc4a5c5,
    0x00000008b64df90f,
    0x00000009c577b611,
    0x0000000a3810f2f5,
    0x0000000af4d75b83,
    0x0000000b59a03fef,
    0x0000000bb1096f85,
    0x0000000d1b92fc76,
    0x0000000d0dd509d2,
    0x0000000e2cfda160,
    0x00000002ff497c63,
    0x000000047240671b,
    0x00000005047a2e55,
    0x0000000635ca87c7,
    0x0000000691254166,
    0x000000068f43d94a,
    0x00000006ef24bdb6,
    0x00000008cdd8f886,
    0x00000009de96b718,
    0x0000000aff6e5a8a,
    0x0000000bae46f029,
    0x0000000d225b6d59,
    0x0000000df8ba8c01,
    0x0000000e3744a22f,
    0x0000000fbb59375d,
    0x000000018a916828,
    0x000000022f29c1ba,
    0x0000000286887d58,
    0x000000041392322e,
    0x000000075d18ecd1,
    0x000000087c302743,
    0x00000008c6317ba9,
    0x00000009e40f36d7,
    0x0000000c0e5a806a,
    0x0000000cc78cb87c,
    0x000000012d2f2d01,
    0x0000000379f36a21,
    0x00000006973f59ac,
    0x00000007789ea9f4,
    0x00000008f1c73e84,
    0x00000008dd287a20,
    0x000000094a4eee4c,
    0x0000000a455379b5,
    0x0000000a9e92987d,
    0x0000000bd25cb40b,
    0x0000000be98d3582,
    0x0000000d3d5972b2,
    0x000000014c53d7c7,
    0x00000004f1796936,
    0x00000004e71fed1a,
    0x000000066d46fae0,
    0x0000000a55abb933,
    0x0000000ebee1acca,
    0x00000001ad4ba6a4,
    0x0000000305b17571,
    0x0000000553611351,
    0x000000059ca62775,
    0x00000007819cb6a1,
    0x0000000edb7bc9eb,
    0x00000005b2694212,
    0x000000072e12d185,
    0x0000000ed6152e2c,
    0x00000005bcdadbf3,
    0x000000078e0aa0c6,
    0x0000000c60a0b909,
    0x0000000ef9a34b0d,
    0x0000000398a6621a,
    0x0000000a8a27c944,
    0x00000004b564304e,
    0x000000052902b4e2,
    0x0000000857280b56,
    0x0000000a91b2c84b,
    0x0000000e91df939b,
    0x00000001fa405f28,
    0x000000023793ab86,
    0x000000068c17729f,
    0x00000009fbf3b840,
    0x000000036922413c,
    0x00000004eb5f946e,
    0x0000000533fe2404,
    0x000000063de7d35e,
    0x0000000925eddc72,
    0x000000099b8b3896,
    0x0000000aace4c708,
    0x0000000c22994af0,
    0x00000008f1eae41b,
    0x0000000d95fb486c,
    0x000000013fb77857,
    0x00000004fe0983a3,
    0x0000000d559bf8a9,
    0x0000000e1855d78d,
    0x0000000fec8daaad,
    0x000000071ecb6d95,
    0x0000000dc9e50e4c,
    0x0000000ca3a4c259,
    0x0000000740d12bbf,
    0x0000000aeedd18e0,
    0x0000000b509b9c8e,
    0x00000005232fea1c,
    0x000000019282d18b,
    0x000000076c22d67b,
    0x0000000936beb34b,
    0x000000008a5ea8dd,
    0x0000000679eadc28,
    0x0000000a08e119c5,
    0x000000020a6e3e24,
    0x00000007eab9c239,
    0x000000096632c32e,
    0x0000000470d06e44,
    0x00000008a70212fb,
    0x00000000a7e4251b,
    0x00000009ec762cc0,
    0x0000000d8a3a1f48,
    0x0000000db680f346,
    0x00000004a1e93a9d,
    0x0000000638ddc04f,
    0x00000004c2fcc993,
    0x000000001ef28c95,
    0x0000000bf0d9792d,
    0x00000006d27557c3,
    0x0000000623f977f4,
    0x000000035b43be57,
    0x0000000bb0c428d5,
    0x0000000a6f01474d,
    0x00000005a70c9749,
    0x000000020ddabc3b,
    0x00000002eabd78cf,
    0x000000090aa18f88,
    0x0000000a9ea89350,
    0x00000003cdb39b22,
    0x0000000839a08f34,
    0x0000000169bb814e,
    0x00000001a575ab08,
    0x0000000a04d3d5a2,
    0x0000000bf7902f2b,
    0x0000000095a5e65c,
    0x000000092e8fce94,
    0x000000067ef48d12,
    0x00000006400dbcac,
    0x0000000b12d8fb9f,
    0x00000000347f45d3,
    0x0000000b35826f56,
    0x0000000c546ac6e4,
    0x000000081cc35b66,
    0x000000041d14bd57,
    0x00000000c052b168,
    0x00000007d6ce5018,
    0x0000000ab4ed5ede,
    0x00000005af817119,
    0x0000000d1454b182,
    0x00000002badb090b,
    0x000000003fcb4c0c,
    0x00000002f1c28fd8,
    0x000000093608c6f7,
    0x00000004c93ba2b5,
    0x000000007d950a5d,
    0x0000000e54b3d3fc,
    0x000000015560cf9d,
    0x0000000189e4958a,
    0x000000062140e9d2,
    0x0000000723bc1cdb,
    0x00000002063f26fa,
    0x0000000fa08ab19f,
    0x00000007955641db,
    0x0000000646b01daa,
    0x000000071cd427cc,
    0x000000009a42f7d4,
    0x0000000717edc643,
    0x000000015eb94367,
    0x00000008392e6bb2,
    0x0000000832408542,
    0x00000002b9b874be,
    0x0000000b21f4730d,
    0x0000000b5d8f24c9,
    0x00000007dbaf6931,
    0x00000001b4e33629,
    0x000000013452e710,
    0x0000000e974af612,
    0x00000001df61d29a,
    0x000000099f2532ad,
    0x0000000e50ec71b4,
    0x00000005df0a36e8,
    0x00000004934e4cea,
    0x0000000e34a0b4bd,
    0x0000000b7b26b588,
    0x00000000f255118d,
    0x0000000d0c8fa31e,
    0x000000006a50c94f,
    0x0000000f28aa9f06,
    0x0000000131d194d8,
    0x0000000622e3da79,
    0x0000000ac7478303,
    0x0000000c8f2521d7,
    0x00000006c9c881f5,
    0x000000049e38b60a,
    0x0000000513d8df65,
    0x0000000d7c2b0785,
    0x00000009f6f9d75a,
    0x00000009f6966020,
    0x00000001e1a54e33,
    0x0000000c04d63419,
    0x0000000946e04cd7,
    0x00000001bdac5902,
    0x000000056469b830,
    0x0000000ffad59569,
    0x000000086970e7d8,
    0x00000008a4b41e12,
    0x0000000ad4688e3b,
    0x000000085f8f5df4,
    0x0000000d833a0893,
    0x00000002a36fdd7c,
    0x0000000d6a857cf2,
    0x00000008829bc35c,
    0x00000005e50d79bc,
    0x0000000fbb8035e4,
    0x0000000c1a95bebf,
    0x0000000036b0baf8,
    0x0000000e0da964ea,
    0x0000000b6483689b,
    0x00000007c8e2f4c1,
    0x00000005b856a23b,
    0x00000002fc183995,
    0x0000000e914b6d70,
    0x0000000b31041969,
    0x00000001bb478493,
    0x0000000063e2b456,
    0x0000000f2a082b9c,
    0x00000008e5e646ea,
    0x000000008172f8f6,
    0x00000000dacd923e,
    0x0000000e5dcf0e2e,
    0x0000000bf9446bae,
    0x00000004822d50d1,
    0x000000026e710bf5,
    0x0000000b90ba2a24,
    0x0000000f3b25aa73,
    0x0000000809ad589b,
    0x000000094cc1e254,
    0x00000005334a3adb,
    0x0000000592886b2f,
    0x0000000bf64704aa,
    0x0000000566dbf24c,
    0x000000072203e692,
    0x000000064e61e809,
    0x0000000d7259aad6,
    0x00000007b924aedc,
    0x00000002df2184e8,
    0x0000000353d1eca7,
    0x0000000fce30d7ce,
    0x0000000f7b0f436e,
    0x000000057e8d8f68,
    0x00000008c79e60db,
    0x00000009c8362b2b,
    0x000000063a5804f2,
    0x00000009298353dc,
    0x00000006f98a71c8,
    0x0000000a5731f693,
    0x000000021ca5c870,
    0x00000001c2107fd3,
    0x00000006181f6c39,
    0x000000019e574304,
    0x0000000329937606,
    0x0000000043d5c70d,
    0x00000009b18ff162,
    0x00000008e2ccfebf,
    0x000000072b7b9b54,
    0x00000009b71f4f3c,
    0x0000000935d7393e,
    0x000000065938881a,
    0x00000006a5bd6f2d,
    0x0000000a19783306,
    0x0000000e6472f4d7,
    0x000000081163df5a,
    0x0000000a838e1cbd,
    0x0000000982748477,
    0x0000000050c54feb,
    0x00000000d82fbb58,
    0x00000002c4c72799,
    0x000000097d259ad6,
    0x000000022d9a43ed,
    0x0000000fdb162a9f,
    0x00000000cb4a727d,
    0x00000004fae2e371,
    0x0000000535b5be8b,
    0x000000048795908a,
    0x0000000ce7c18962,
    0x00000004ea154d80,
    0x000000050c064889,
    0x00000008d97fc75d,
    0x0000000c8bd9ec61,
    0x000000083ee8e8bb,
    0x0000000c8431419a,
    0x00000001aa78079d,
    0x00000008111aa4a5,
    0x0000000dfa3a69fe,
    0x000000051630d83f,
    0x00000002d930fb3f,
    0x00000002133116e5,
    0x0000000ae5395522,
    0x0000000bc07a4e8a,
    0x000000057bf08ba0,
    0x00000006cb18036a,
    0x0000000f0e2e4b75,
    0x00000003eb692b6f,
    0x0000000d8178a3fa,
    0x0000000238cce6a6,
    0x0000000e97d5cdd7,
    0x0000000fe10d8d5e,
    0x0000000b39584a1d,
    0x0000000ca03536fd,
    0x0000000aa61f3998,
    0x000000072ff23ec2,
    0x000000015aa7d770,
    0x000000057a3a1282,
    0x0000000d1f3902dc,
    0x00000006554c9388,
    0x0000000fd01283c7,
    0x0000000e8baa42c5,
    0x000000072cee6adf,
    0x0000000f6614b3fa,
    0x000000095c3778a2,
    0x00000007da4cea7a,
    0x0000000d18a5912c,
    0x0000000d116426e5,
    0x000000027c17bc1c,
    0x0000000b95b53bc1,
    0x0000000c8f937a05,
    0x0000000ed220c9bd,
    0x00000000c97d72ab,
    0x00000008fb1217ae,
    0x000000025ca8a5a1,
    0x0000000b261b871b,
    0x00000001bef0a056,
    0x0000000806a51179,
    0x0000000eed249145,
    0x00000003f82aeceb,
    0x0000000cc56e9acf,
    0x00000002e78d01eb,
    0x0000000102cee17f,
    0x000000037caad3d5,
    0x000000016ac5b1ee,
    0x00000002af164ece,
    0x0000000d4cd81dc9,
    0x000000012263a7e7,
    0x000000057ac7d117,
    0x00000009391d9740,
    0x00000007aedaa77f,
    0x00000009675a3c72,
    0x0000000277f25191,
    0x0000000ebb6e64b9,
    0x00000007ad3ef747,
    0x000000012759b181,
    0x0000000948257d4d,
    0x0000000b63a850f6,
    0x00000003a52a8f75,
    0x00000004a019532c,
    0x0000000a021a7529,
    0x0000000cc661876d,
    0x00000004085afd05,
    0x0000000e7048e089,
    0x00000003f979cdc6,
    0x0000000d9da9071b,
    0x0000000ed2fc5b68,
    0x000000079d64c3a1,
    0x0000000fd44e2361,
    0x00000008eea46a74,
    0x000000042233b9c2,
    0x0000000ae4d1765d,
    0x00000007303a094c,
    0x00000002d7033abe,
    0x00000003dcc2b0b4,
    0x00000000f0967d09,
    0x000000006f0cd7de,
    0x000000009807aca0,
    0x00000003a295cad3,
    0x00000002b106b202,
    0x00000003f38a828e,
    0x000000078af46596,
    0x0000000bda2dc713,
    0x00000009a8c8c9d9,
    0x00000006a0f2ddce,
    0x0000000a76af6fe2,
    0x0000000086f66fa4,
    0x0000000d52d63f8d,
    0x000000089f7a6e73,
    0x0000000cc6b23362,
    0x0000000b4ebf3c39,
    0x0000000564f300fa,
    0x0000000e8de3a706,
    0x000000079a033b61,
    0x0000000765e160c5,
    0x0000000a266a4f85,
    0x0000000a68c38c24,
    0x0000000dca0711fb,
    0x000000085fba85ba,
    0x000000037a207b46,
    0x0000000158fcc4d0,
    0x00000000569d79b3,
    0x00000007b1a25555,
    0x0000000a8ae22468,
    0x00000007c592bdfd,
    0x00000000c59a5f66,
    0x0000000b1115daa3,
    0x0000000f17c87177,
    0x00000006769d766b,
    0x00000002b637356d,
    0x000000013d8685ac,
    0x0000000f24cb6ec0,
    0x00000000bd0b56d1,
    0x000000042ff0e26d,
    0x0000000b41609267,
    0x000000096f9518af,
    0x0000000c56f96636,
    0x00000004a8e10349,
    0x0000000863512171,
    0x0000000ea455d86c,
    0x0000000bd0e25279,
    0x0000000e65e3f761,
    0x000000036c84a922,
    0x000000085fd1b38f,
    0x0000000657c91539,
    0x000000015033fe04,
    0x000000009051c921,
    0x0000000ab27d80d8,
    0x0000000f92f7d0a1,
    0x00000008eb6bb737,
    0x000000010b5b0f63,
    0x00000006c9c7ad63,
    0x0000000f66fe70ae,
    0x0000000ca579bd92,
    0x0000000956198e4d,
    0x000000029e4405e5,
    0x0000000e44eb885c,
    0x000000041612456c,
    0x0000000ea45e0abf,
    0x0000000d326529bd,
    0x00000007b2c33cef,
    0x000000080bc9b558,
    0x00000007169b9740,
    0x0000000c37f99209,
    0x000000031ff6dab9,
    0x0000000c795190ed,
    0x0000000a7636e95f,
    0x00000009df075841,
    0x000000055a083932,
    0x0000000a7cbdf630,
    0x0000000409ea4ef0,
    0x000000092a1991b6,
    0x00000004b078dee9,
    0x0000000ae18ce9e4,
    0x00000005a6e1ef35,
    0x00000001a403bd59,
    0x000000031ea70a83,
    0x00000002bc3c4f3a,
    0x00000005c921b3cb,
    0x0000000042da05c5,
    0x00000001f667d16b,
    0x0000000416a368cf,
    0x0000000fbc0a7a3b,
    0x00000009419f0c7c,
    0x000000081be2fa03,
    0x000000034e2c172f,
    0x000000028648d8ae,
    0x0000000c7acbb885,
    0x000000045f31eb6a,
    0x0000000d1cfc0a7b,
    0x000000042c4d260d,
    0x0000000cf6584097,
    0x000000094b132b14,
    0x00000003c5c5df75,
    0x00000008ae596fef,
    0x0000000aea8054eb,
    0x00000000ae9cc573,
    0x0000000496fb731b,
    0x0000000ebf105662,
    0x0000000af9c83a37,
    0x0000000c0d64cd6b,
    0x00000007b608159a,
    0x0000000e74431642,
    0x0000000d6fb9d900,
    0x0000000291e99de0,
    0x000000010500ba9a,
    0x00000005cd05d037,
    0x0000000a87254fb2,
    0x00000009d7824a37,
    0x00000008b2c7b47c,
    0x000000030c788145,
    0x00000002f4e5a8be,
    0x0000000badb884da,
    0x0000000026e0d5c9,
    0x00000006fdbaa32e,
    0x000000034758eb31,
    0x0000000565cd1b4f,
    0x00000002bfd90fb0,
    0x0000000093052a6b,
    0x0000000d3c13c4b9,
    0x00000002daea43bf,
    0x0000000a279762bc,
    0x0000000f1bd9f22c,
    0x00000004b7fec94f,
    0x0000000545761d5a,
    0x00000007327df411,
    0x00000001b52a442e,
    0x000000049b0ce108,
    0x000000024c764bc8,
    0x0000000374563045,
    0x0000000a3e8f91c6,
    0x00000000e6bd2241,
    0x0000000e0e52ee3c,
    0x000000007e8e3caa,
    0x000000096c2b7372,
    0x000000033acbdfda,
    0x0000000b15d91e54,
    0x0000000464759ac1,
    0x00000006886a1998,
    0x000000057f5d3958,
    0x00000005a1f5c1f5,
    0x00000000b58158ad,
    0x0000000e712053fb,
    0x00000005352ddb25,
    0x0000000414b98ea0,
    0x000000074f89f546,
    0x000000038a56b3c3,
    0x000000038db0dc17,
    0x0000000aa016a755,
    0x0000000dc72366f5,
    0x00000000cee93d75,
    0x0000000b2fe7a56b,
    0x0000000a847ed390,
    0x00000008713ef88c,
    0x0000000a217cc861,
    0x00000008bca25d7b,
    0x0000000455526818,
    0x0000000ea3a7a180,
    0x0000000a9536e5e0,
    0x00000009b64a1975,
    0x00000005bfc756bc,
    0x0000000046aa169b,
    0x000000053a17f76f,
    0x00000004d6815274,
    0x0000000cca9cf3f6,
    0x00000004013fcb8b,
    0x00000003d26cdfa5,
    0x00000005786231f7,
    0x00000007d4ab09ab,
    0x0000000960b5ffbc,
    0x00000008914df0d4,
    0x00000002fc6f2213,
    0x0000000ac235637e,
    0x0000000151b28ed3,
    0x000000046f79b6db,
    0x00000001382e0c9f,
    0x000000053abf983a,
    0x0000000383c47ade,
    0x00000003fcf88978,
    0x0000000eb9079df7,
    0x000000009af0714d,
    0x0000000da19d1bb7,
    0x00000009a02749f8,
    0x00000001c62dab9b,
    0x00000001a137e44b,
    0x00000002867718c7,
    0x000000035815525b,
    0x00000007cd35c550,
    0x00000002164f73a0,
    0x0000000e8b772fe0,
];

/// The printed 10×10 cells of tag36h11 `id` (`true` = white), `[row][col]` with row 0 at
/// the top and col 0 at the left of the printed tag; `None` for `id ≥ 587`.
pub fn tag36h11_cells(id: u32) -> Option<[[bool; TAG36H11_TOTAL_CELLS]; TAG36H11_TOTAL_CELLS]> {
    let code = *TAG36H11_CODES.get(usize::try_from(id).ok()?)?;
    // White outer ring, black inner ring, data bits inside.
    let mut cells = [[false; TAG36H11_TOTAL_CELLS]; TAG36H11_TOTAL_CELLS];
    for (r, row) in cells.iter_mut().enumerate() {
        for (c, cell) in row.iter_mut().enumerate() {
            *cell =
                r == 0 || c == 0 || r == TAG36H11_TOTAL_CELLS - 1 || c == TAG36H11_TOTAL_CELLS - 1;
        }
    }
    for i in 0..36 {
        let bit = (code >> (35 - i)) & 1 == 1;
        let r = usize::from(TAG36H11_BIT_Y[i]) + 1;
        let c = usize::from(TAG36H11_BIT_X[i]) + 1;
        cells[r][c] = bit;
    }
    Some(cells)
}

/// Reflectance of tag36h11 board `id` at board coordinates `(u, v)` (`u` right, `v` down,
/// `[0, 1]²` covering the 10×10 cells including the white border): [`TAG_BLACK_ALBEDO`]
/// or [`TAG_WHITE_ALBEDO`].
///
/// Points outside the board (or NaN) read as white paper; an `id ≥ 587` reads as a blank
/// white board. For repeated lookups build a [`TagBoard`] once.
pub fn tag_board_albedo(id: u32, u: f32, v: f32) -> f32 {
    match TagBoard::new(id) {
        Some(board) => board.albedo(u, v),
        None => TAG_WHITE_ALBEDO,
    }
}

/// A printed tag36h11 board: the id and its decoded cells, for fast albedo lookups.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TagBoard {
    id: u32,
    cells: [[bool; TAG36H11_TOTAL_CELLS]; TAG36H11_TOTAL_CELLS],
}

impl TagBoard {
    /// The board of tag36h11 `id`; `None` for `id ≥ 587`.
    pub fn new(id: u32) -> Option<TagBoard> {
        Some(TagBoard {
            id,
            cells: tag36h11_cells(id)?,
        })
    }

    /// The tag id.
    pub fn id(&self) -> u32 {
        self.id
    }

    /// The printed cells (`true` = white), as [`tag36h11_cells`].
    pub fn cells(&self) -> &[[bool; TAG36H11_TOTAL_CELLS]; TAG36H11_TOTAL_CELLS] {
        &self.cells
    }

    /// Whether board point `(u, v)` is white; points outside `[0, 1]²` (or NaN) are white.
    pub fn is_white(&self, u: f32, v: f32) -> bool {
        match (cell_index(u), cell_index(v)) {
            (Some(c), Some(r)) => self.cells[r][c],
            _ => true,
        }
    }

    /// Reflectance at board point `(u, v)` (point sample).
    pub fn albedo(&self, u: f32, v: f32) -> f32 {
        if self.is_white(u, v) {
            TAG_WHITE_ALBEDO
        } else {
            TAG_BLACK_ALBEDO
        }
    }

    /// Mean reflectance over the axis-aligned box `[u ± half_u] × [v ± half_v]` of board
    /// coordinates (exact box filter over the cells; outside the board is white paper).
    /// Use it to anti-alias a ray's footprint; zero half-widths give [`TagBoard::albedo`].
    pub fn albedo_box(&self, u: f32, v: f32, half_u: f32, half_v: f32) -> f32 {
        let (hu, hv) = (half_u.abs(), half_v.abs());
        if !(hu > 0.0 && hv > 0.0) {
            return self.albedo(u, v);
        }
        let n = TAG36H11_TOTAL_CELLS as f32;
        let (u0, u1, v0, v1) = ((u - hu) * n, (u + hu) * n, (v - hv) * n, (v + hv) * n);
        let mut black = 0.0f32;
        for (r, row) in self.cells.iter().enumerate() {
            let lv = overlap(v0, v1, r as f32);
            if lv <= 0.0 {
                continue;
            }
            for (c, &white) in row.iter().enumerate() {
                if !white {
                    black += lv * overlap(u0, u1, c as f32);
                }
            }
        }
        let frac = (black / ((u1 - u0) * (v1 - v0))).clamp(0.0, 1.0);
        TAG_WHITE_ALBEDO + (TAG_BLACK_ALBEDO - TAG_WHITE_ALBEDO) * frac
    }
}

/// Length of the overlap of `[a, b]` with the cell `[k, k + 1]`.
fn overlap(a: f32, b: f32, k: f32) -> f32 {
    (b.min(k + 1.0) - a.max(k)).max(0.0)
}

/// The cell index of a board coordinate, `None` outside `[0, 1]` or NaN (1.0 itself is in
/// the last cell).
fn cell_index(t: f32) -> Option<usize> {
    if (0.0..=1.0).contains(&t) {
        Some(((t * TAG36H11_TOTAL_CELLS as f32) as usize).min(TAG36H11_TOTAL_CELLS - 1))
    } else {
        None
    }
}

/// The tag-frame point of board coordinates `(u, v)` for AprilTag tag size `tag_size`
/// (edge of the black square, m): `((u − 0.5)·1.25·s, (v − 0.5)·1.25·s, 0)`.
pub fn board_to_tag_frame(u: f64, v: f64, tag_size: f64) -> [f64; 3] {
    let k = BOARD_PER_TAG_SIZE * tag_size;
    [(u - 0.5) * k, (v - 0.5) * k, 0.0]
}

/// The board coordinates `(u, v)` of tag-frame point `(x, y)` (`z` ignored) for tag size
/// `tag_size`; inverse of [`board_to_tag_frame`].
pub fn tag_frame_to_board(x: f64, y: f64, tag_size: f64) -> [f64; 2] {
    let k = BOARD_PER_TAG_SIZE * tag_size;
    [x / k + 0.5, y / k + 0.5]
}

/// The four corners of the black square in the tag frame, in AprilTag's detection order
/// (bottom-left, bottom-right, top-right, top-left as printed; see the module docs).
pub fn tag_corners(tag_size: f64) -> [[f64; 3]; 4] {
    let h = 0.5 * tag_size;
    [[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]]
}

/// The four corners of the black square in board coordinates, in AprilTag's detection
/// order (see [`tag_corners`]).
pub const TAG_CORNERS_BOARD_UV: [[f64; 2]; 4] = [[0.1, 0.9], [0.9, 0.9], [0.9, 0.1], [0.1, 0.1]];

#[cfg(test)]
mod tests {
    use super::*;
    use apriltag::{DetectorBuilder, Family, Image};
    use nalgebra::{Matrix3, Vector3};

    #[test]
    fn table_matches_apriltag3_source() {
        assert_eq!(TAG36H11_CODES.len(), 587);
        assert_eq!(TAG36H11_CODES[0], 0x0000000d7e00984b);
        assert_eq!(TAG36H11_CODES[1], 0x0000000dda664ca7);
        assert_eq!(TAG36H11_CODES[2], 0x0000000dc4a1c821);
        assert_eq!(TAG36H11_CODES[42], 0x0000000d225b6d59);
        assert_eq!(TAG36H11_CODES[584], 0x00000007cd35c550);
        assert_eq!(TAG36H11_CODES[585], 0x00000002164f73a0);
        assert_eq!(TAG36H11_CODES[586], 0x0000000e8b772fe0);
        assert!(TAG36H11_CODES.iter().all(|&c| c < 1 << 36));
        // The bit layout covers each inner cell once.
        let mut seen = [[false; 6]; 6];
        for i in 0..36 {
            let (x, y) = (TAG36H11_BIT_X[i], TAG36H11_BIT_Y[i]);
            assert!((1..=6).contains(&x) && (1..=6).contains(&y));
            assert!(!seen[usize::from(y) - 1][usize::from(x) - 1]);
            seen[usize::from(y) - 1][usize::from(x) - 1] = true;
        }
    }

    /// Re-encodes the 6×6 data cells of a board with the bit layout.
    fn encode(cells: &[[bool; 10]; 10]) -> u64 {
        (0..36).fold(0u64, |acc, i| {
            let r = usize::from(TAG36H11_BIT_Y[i]) + 1;
            let c = usize::from(TAG36H11_BIT_X[i]) + 1;
            (acc << 1) | u64::from(cells[r][c])
        })
    }

    /// The board turned 90° clockwise.
    fn rotate(cells: &[[bool; 10]; 10]) -> [[bool; 10]; 10] {
        std::array::from_fn(|r| std::array::from_fn(|c| cells[9 - c][r]))
    }

    /// tag36h11 has minimum Hamming distance 11 over all pairs and rotations; a wrong
    /// table or bit layout breaks this.
    #[test]
    fn minimum_hamming_distance_is_11_under_rotation() {
        let rotations: Vec<[u64; 4]> = (0..587)
            .map(|id| {
                let mut cells = tag36h11_cells(id).expect("valid id");
                assert_eq!(encode(&cells), TAG36H11_CODES[id as usize]);
                std::array::from_fn(|_| {
                    let code = encode(&cells);
                    cells = rotate(&cells);
                    code
                })
            })
            .collect();
        let mut min_d = u32::MAX;
        for (i, ri) in rotations.iter().enumerate() {
            for rot in &ri[1..] {
                min_d = min_d.min((ri[0] ^ rot).count_ones());
            }
            for rj in &rotations[i + 1..] {
                for rot in rj {
                    min_d = min_d.min((ri[0] ^ rot).count_ones());
                }
            }
        }
        assert_eq!(min_d, 11);
    }

    #[test]
    fn cells_have_borders_and_invalid_ids_are_none() {
        for id in [0, 1, 42, 586] {
            let cells = tag36h11_cells(id).expect("valid id");
            // White outer ring.
            assert!(cells[0].iter().chain(&cells[9]).all(|&w| w));
            assert!(cells.iter().all(|row| row[0] && row[9]));
            // Black inner ring.
            assert!(cells[1][1..9].iter().chain(&cells[8][1..9]).all(|&w| !w));
            assert!(cells[1..9].iter().all(|row| !row[1] && !row[8]));
        }
        assert!(tag36h11_cells(587).is_none());
        assert!(TagBoard::new(u32::MAX).is_none());
        assert_eq!(tag_board_albedo(587, 0.5, 0.5), TAG_WHITE_ALBEDO);
        // Tag 0 row by row, as AprilTag 3's tag36h11 image of id 0 (0 = black).
        let rows: Vec<String> = tag36h11_cells(0)
            .expect("valid id")
            .iter()
            .map(|row| row.iter().map(|&w| if w { '1' } else { '0' }).collect())
            .collect();
        println!("tag36_11_00000:\n{}", rows.join("\n"));
    }

    #[test]
    fn albedo_lookup_and_box_filter() {
        let board = TagBoard::new(42).expect("valid id");
        assert_eq!(board.id(), 42);
        assert_eq!(board.albedo(0.05, 0.5), TAG_WHITE_ALBEDO);
        assert_eq!(board.albedo(0.15, 0.5), TAG_BLACK_ALBEDO);
        assert_eq!(board.albedo(-0.5, f32::NAN), TAG_WHITE_ALBEDO);
        assert_eq!(board.albedo(1.0, 1.0), TAG_WHITE_ALBEDO);
        // Half of the box on the white ring, half on the black ring.
        let a = board.albedo_box(0.1, 0.5, 0.02, 0.02);
        assert!((a - 0.5 * (TAG_WHITE_ALBEDO + TAG_BLACK_ALBEDO)).abs() < 1e-5);
        // A box covering the whole board and much paper around it.
        let black = board.cells().iter().flatten().filter(|&&w| !w).count() as f32;
        let a = board.albedo_box(0.5, 0.5, 1.0, 1.0);
        let expect = TAG_WHITE_ALBEDO + (TAG_BLACK_ALBEDO - TAG_WHITE_ALBEDO) * black / 400.0;
        assert!((a - expect).abs() < 1e-5);
        for id in 0..587 {
            assert_eq!(
                tag_board_albedo(id, 0.35, 0.45),
                TagBoard::new(id).expect("valid").albedo(0.35, 0.45)
            );
        }
    }

    #[test]
    fn tag_frame_mapping() {
        let s = 0.16;
        let corners = tag_corners(s);
        for (uv, xyz) in TAG_CORNERS_BOARD_UV.iter().zip(corners) {
            let p = board_to_tag_frame(uv[0], uv[1], s);
            for k in 0..3 {
                assert!((p[k] - xyz[k]).abs() < 1e-12);
            }
            let back = tag_frame_to_board(p[0], p[1], s);
            assert!((back[0] - uv[0]).abs() < 1e-12 && (back[1] - uv[1]).abs() < 1e-12);
        }
    }

    /// Homography mapping the unit square's corners (0,0), (1,0), (1,1), (0,1) to `q`.
    fn square_to_quad(q: [[f64; 2]; 4]) -> Matrix3<f64> {
        let [[x0, y0], [x1, y1], [x2, y2], [x3, y3]] = q;
        let (dx1, dx2, dx3) = (x1 - x2, x3 - x2, x0 - x1 + x2 - x3);
        let (dy1, dy2, dy3) = (y1 - y2, y3 - y2, y0 - y1 + y2 - y3);
        let den = dx1 * dy2 - dx2 * dy1;
        let g = (dx3 * dy2 - dx2 * dy3) / den;
        let h = (dx1 * dy3 - dx3 * dy1) / den;
        Matrix3::new(
            x1 - x0 + g * x1,
            x3 - x0 + h * x3,
            x0,
            y1 - y0 + g * y1,
            y3 - y0 + h * y3,
            y0,
            g,
            h,
            1.0,
        )
    }

    fn apply(h: &Matrix3<f64>, u: f64, v: f64) -> [f64; 2] {
        let p = h * Vector3::new(u, v, 1.0);
        [p.x / p.z, p.y / p.z]
    }

    /// Draws boards (`id`, image corners of the board's (0,0), (1,0), (1,1), (0,1)) onto
    /// white paper, 8×8 supersampled; pixel (x, y) covers [x, x+1) × [y, y+1).
    fn draw(width: usize, height: usize, boards: &[(u32, [[f64; 2]; 4])]) -> Image {
        let mut image = Image::zeros_with_stride(width, height, width).expect("image");
        let tags: Vec<(TagBoard, Matrix3<f64>)> = boards
            .iter()
            .map(|&(id, q)| {
                let h = square_to_quad(q).try_inverse().expect("invertible");
                (TagBoard::new(id).expect("valid id"), h)
            })
            .collect();
        const SS: usize = 8;
        for y in 0..height {
            for x in 0..width {
                let mut sum = 0.0f64;
                for sy in 0..SS {
                    for sx in 0..SS {
                        let px = x as f64 + (sx as f64 + 0.5) / SS as f64;
                        let py = y as f64 + (sy as f64 + 0.5) / SS as f64;
                        let mut a = TAG_WHITE_ALBEDO;
                        for (board, h_inv) in &tags {
                            let [u, v] = apply(h_inv, px, py);
                            if (0.0..=1.0).contains(&u) && (0.0..=1.0).contains(&v) {
                                a = board.albedo(u as f32, v as f32);
                            }
                        }
                        sum += f64::from(a);
                    }
                }
                image[(x, y)] = (255.0 * sum / (SS * SS) as f64).round() as u8;
            }
        }
        image
    }

    #[test]
    fn real_apriltag_detector_reads_ids_and_corners() {
        // Four boards at ~20 px per cell with mild perspective, one of them turned
        // upside down and one a quarter turn, on white paper.
        let boards: Vec<(u32, [[f64; 2]; 4])> = vec![
            (
                0,
                [[40.3, 30.7], [243.1, 38.2], [238.4, 236.9], [35.2, 228.4]],
            ),
            (
                1,
                [[520.6, 262.2], [318.9, 251.5], [322.7, 45.1], [526.4, 56.8]],
            ),
            (
                42,
                [[237.2, 320.4], [244.8, 522.9], [41.5, 515.3], [36.1, 315.8]],
            ),
            (
                586,
                [
                    [322.4, 318.6],
                    [515.7, 330.3],
                    [530.2, 541.2],
                    [310.8, 527.7],
                ],
            ),
        ];
        let image = draw(580, 580, &boards);
        for decimate in [1.0f32, 2.0] {
            let mut detector = DetectorBuilder::new()
                .add_family_bits(Family::tag_36h11(), 1)
                .build()
                .expect("detector");
            detector.set_decimation(decimate);
            let detections = detector.detect(&image);
            let mut ids: Vec<usize> = detections.iter().map(|d| d.id()).collect();
            ids.sort_unstable();
            assert_eq!(ids, vec![0, 1, 42, 586], "decimate {decimate}");
            for det in &detections {
                let (_, q) = boards
                    .iter()
                    .find(|b| b.0 as usize == det.id())
                    .expect("drawn");
                let h = square_to_quad(*q);
                assert_eq!(det.hamming(), 0);
                for (k, (got, uv)) in det.corners().iter().zip(TAG_CORNERS_BOARD_UV).enumerate() {
                    let want = apply(&h, uv[0], uv[1]);
                    let err = (got[0] - want[0]).hypot(got[1] - want[1]);
                    println!(
                        "decimate {decimate} id {} corner {k}: detected ({:.2}, {:.2}) expected ({:.2}, {:.2}) err {err:.3} px",
                        det.id(),
                        got[0],
                        got[1],
                        want[0],
                        want[1]
                    );
                    assert!(err < 1.0, "id {} corner {k} off by {err} px", det.id());
                }
            }
        }
    }
}
