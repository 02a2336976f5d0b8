// Four lathes of POV-Ray's curve kinds, written for lathe_shape (issue 13):
// an open metal cup (bezier_spline, a single sheet), a Bezier vase, a
// Catmull-Rom (cubic_spline) goblet and a sor bottle. Units: cm, +y up.
//
//   povray +Ipov_samples.pov +W640 +H360          (POV-Ray 3.7)
//   lathe-profile --from-pov pov_samples.pov -o profiles
//
// writes profiles/<name>.csv and a <shape type="lathe"> snippet per block;
// pov_samples.xml is the same scene for Mitsuba.
#version 3.7;
global_settings { assumed_gamma 1.0 }

camera { location <0, 14, -48> look_at <0, 4.5, 0> angle 36 }
light_source { <-30, 40, -30> color rgb 1.2 }
background { color rgb 0.4 }
plane { y, 0 pigment { checker color rgb 0.1 color rgb 0.8 scale 2 } }

// Open cup: the bottom runs out from the axis and turns up into the wall;
// the rim is a free edge.
#declare Cup = lathe {
  bezier_spline
  8,
  <0, 0>, <1.5, 0>, <2.8, 0.1>, <3.0, 0.6>,
  <3.0, 0.6>, <3.2, 1.1>, <3.0, 4.0>, <3.6, 6.0>
  pigment { color rgb <0.9, 0.6, 0.3> } finish { metallic reflection 0.8 }
  translate <-9, 0.001, 0>
}

// Vase: two Bezier segments up the outside, one across the top to the axis.
#declare Vase = lathe {
  bezier_spline
  12,
  <0, 0>, <2.2, 0>, <2.6, 0.5>, <2.6, 2.5>,
  <2.6, 2.5>, <2.6, 5.5>, <0.8, 6.2>, <1.1, 8.5>,
  <1.1, 8.5>, <1.2, 9.0>, <0.6, 9.0>, <0, 9.0>
  pigment { color rgb <0.2, 0.35, 0.7> }
  translate <-3, 0.001, 0>
}

// Goblet: foot, stem, outer bowl up to the rim, inner bowl back to the axis.
// The first and last points only set the end tangents.
#declare Goblet = lathe {
  cubic_spline
  14,
  <0, -0.2>, <0, 0>, <2.5, 0.1>, <2.4, 0.35>, <0.35, 0.6>, <0.3, 3.5>, <1.5, 4.3>,
  <2.6, 6.0>, <2.8, 8.0>, <2.65, 8.05>, <2.45, 6.2>, <1.4, 4.7>, <0, 4.4>, <0, 4.2>
  sturm
  pigment { color rgbf <1, 1, 1, 0.9> } finish { reflection 0.1 }
  translate <3, 0.001, 0>
}

// Bottle: r^2 a cubic in the height; closed by discs at both ends.
#declare Bottle = sor {
  8,
  <1.8, -1>, <2.0, 0>, <2.1, 3>, <2.0, 5.5>, <1.2, 7>, <0.6, 8.5>, <0.6, 10>, <0.7, 10.5>
  pigment { color rgbf <0.85, 1, 0.85, 0.9> } interior { ior 1.5 }
  translate <9, 0.001, 0>
}

object { Cup }
object { Vase }
object { Goblet }
object { Bottle }
